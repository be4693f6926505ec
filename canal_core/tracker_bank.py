"""Tracker states of many streams of one model held as arrays, stepped together.

:class:`TrackerBank` is what the live bridge keeps per model: a stream owns a slot; one call
steps any set of slots through the compiled kernel (:mod:`canal_core.tracker_kernel`), the
numpy pass (:mod:`canal_core.tracker_batch`) or the scalar step (:mod:`canal_core.tracker`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .tracker import (
    FAR_ETA,
    MAX_ADVANCE,
    MAX_ONWARD,
    MAX_PLAN_ETA,
    REPLAN_TOLERANCE,
    SUSTAIN,
    WINDOW,
    TrackerGeometry,
    TrackerState,
    tracker_step,
)
from .tracker_batch import TrackerBatch, batched_tracker_step, step_tables
from .tracker_kernel import compiled_step_rows, packed_width
from .tracker_obstacles import BLOCKED, DETOUR, OK, SceneTables, avoided_targets
from .tube import TUBE_MARGIN
from .validation import FloatArray

#: Batches of at least this many rows take :class:`TrackerBank`'s vectorised pass; a single
#: row the scalar step (one vectorised pass costs about what 2-2.5 scalar steps do, at any
#: batch size up to a few dozen rows: the cost is numpy calls, not rows).
VECTORISE_FROM = 2


class TrackerBank:
    """The tracker states of many streams of one model, held as arrays.

    A stream owns a *slot* (:meth:`add`); :meth:`step` steps any set of slots in one
    vectorised pass that reads and writes the state arrays directly, with no per-stream
    Python object on the way in or out. The answers equal :func:`tracker_step` on each
    slot's state (same sections, flags and plan; floats up to the last bits of a reordered
    sum). For circle sections (N >= 3) the pass is the compiled
    :func:`canal_core.tracker_kernel.step_rows` once it is compiled
    (:func:`canal_core.tracker_kernel.compile_step_rows`; about 1 us a call plus a fraction
    of a microsecond a row), else :func:`batched_tracker_step` (numpy, 30-60 us a call);
    non-circular sections, canals of fewer than three sections and numpy batches under
    :data:`VECTORISE_FROM` rows take the scalar step.

    Parameters
    ----------
    geometry : TrackerGeometry
    lookahead : int
        Sections ahead of the located one to aim at (>= 1).
    replan_tolerance : float
        As :func:`tracker_step`.
    capacity : int
        Slots allocated up front (the arrays double when full).
    compiled : bool
        Step with the compiled kernel when it is compiled (False: always numpy).
    """

    def __init__(self, geometry: TrackerGeometry, lookahead: int = 1,
                 replan_tolerance: float = REPLAN_TOLERANCE, capacity: int = 16,
                 compiled: bool = True) -> None:
        self.geometry = geometry
        self.lookahead = max(int(lookahead), 1)
        self.replan_tolerance = float(replan_tolerance)
        k = geometry.basis.shape[1]
        cap = max(int(capacity), 1)
        #: section reached per slot (never decreases while stepped)
        self.index = np.zeros(cap, dtype=np.intp)
        #: planned ratio per slot; NaN: no plan yet
        self.eta = np.full(cap, np.nan)
        #: planned unit in-plane direction per slot, shape (capacity, D - 1)
        self.direction = np.zeros((cap, k))
        #: the slot's last suspect pose and the streak's length (0: none)
        self.pending = np.zeros((cap, k + 1))
        self.strikes = np.zeros(cap, dtype=np.intp)
        self._free = list(range(cap - 1, -1, -1))
        #: the scene every answer goes around (:meth:`avoid_packed`); None: no obstacles
        self.scene: SceneTables | None = None
        self._isotropic = bool(geometry.sections.spec.isotropic) and geometry.centres.shape[0] >= 3
        self.compiled = bool(compiled)
        self._kernel_arrays: tuple[Any, ...] = ()
        if self._isotropic:
            # built with the bank (where a model is loaded), not by its first step, which
            # runs on a live worker while every other stream waits
            tables = step_tables(geometry)
            g = geometry
            self._kernel_arrays = tuple(np.ascontiguousarray(a, dtype=np.float64) for a in (
                g.centres, g.tangents, g.offsets, g.basis, tables.radius, tables.curvature,
                np.zeros(0) if g.section_times is None else g.section_times,
                np.zeros((0, 4)) if g.orientations is None else g.orientations,
                tables.default_direction))

    def __len__(self) -> int:
        """Slots in use."""
        return int(self.index.shape[0]) - len(self._free)

    def add(self, index: int = 0) -> int:
        """A free slot, started at section ``index`` with no plan."""
        if not self._free:
            cap = self.index.shape[0]
            self.index = np.concatenate([self.index, np.zeros(cap, dtype=np.intp)])
            self.eta = np.concatenate([self.eta, np.full(cap, np.nan)])
            self.direction = np.concatenate([self.direction, np.zeros_like(self.direction)])
            self.pending = np.concatenate([self.pending, np.zeros_like(self.pending)])
            self.strikes = np.concatenate([self.strikes, np.zeros(cap, dtype=np.intp)])
            self._free = list(range(2 * cap - 1, cap - 1, -1))
        slot = self._free.pop()
        self.reset(slot, index)
        return slot

    def release(self, slot: int) -> None:
        """Give ``slot`` back (its stream is gone)."""
        self.reset(slot, 0)
        self._free.append(int(slot))

    def reset(self, slot: int, index: int = 0) -> None:
        """Start ``slot`` over from section ``index`` (clamped to the canal's sections) with
        no plan."""
        self.index[slot] = min(max(int(index), 0), self.geometry.centres.shape[0] - 1)
        self.eta[slot] = np.nan
        self.strikes[slot] = 0

    def seed(self, slot: int, position: FloatArray, index: int) -> bool:
        """Start ``slot`` as a stream with no plan that was stepped with ``position`` (D,)
        from section ``index``: placed there, with the plan that step makes, when the
        position is near the canal (True); else started over from the first section with
        no plan (False)."""
        self.reset(slot, index)
        before = self.state(slot)
        with np.errstate(all="ignore"):
            _, after = tracker_step(self.geometry, before, np.asarray(position, dtype=np.float64),
                                    self.lookahead, self.replan_tolerance)
        if after is before:  # far from the canal: a stream with no plan is left as it was
            self.reset(slot, 0)
            return False
        self._keep(slot, after)
        return True

    def state(self, slot: int) -> TrackerState:
        """``slot``'s state as a :class:`TrackerState`."""
        eta = float(self.eta[slot])
        strikes = int(self.strikes[slot])
        pending = self.pending[slot].copy() if strikes else None
        if math.isnan(eta):
            return TrackerState(int(self.index[slot]), None, None, pending, strikes)
        return TrackerState(int(self.index[slot]), eta, self.direction[slot].copy(), pending,
                            strikes)

    def step(self, slots: Any, positions: FloatArray) -> TrackerBatch:
        """Step the given slots (distinct) with their live positions, shape (B, D)."""
        p = np.asarray(positions, dtype=np.float64)
        kernel = self._kernel()
        if kernel is not None:
            return self._batch_of_rows(self._compiled_rows(kernel, slots, p))
        return self._numpy_step(slots, p)

    def step_packed(self, slots: Any, positions: FloatArray) -> FloatArray:
        """:meth:`step`'s answers packed one row per slot, as the compiled kernel writes
        them (:func:`canal_core.tracker_kernel.step_rows`): target (D), progress, eta,
        section, inside (1.0/0.0), done (1.0/0.0), velocity (D), orientation (4); velocity
        and orientation NaN when the model has none.

        Parameters
        ----------
        slots : sequence of int, length B
            Distinct slots.
        positions : array, shape (B, D)

        Returns
        -------
        rows : array, shape (B, 2 D + 9)
            A caller reads every answer with one ``tolist()`` (the live bridge's path).
        """
        p = np.asarray(positions, dtype=np.float64)
        kernel = self._kernel()
        if kernel is not None:
            return self._compiled_rows(kernel, slots, p)
        return self._rows_of_batch(self._numpy_step(slots, p))

    def avoid_packed(self, rows: FloatArray, positions: FloatArray,
                     slots: Any = None) -> NDArray[np.int8] | None:
        """Correct packed answers (:meth:`step_packed`) for the bank's scene, in place, in one
        vectorised pass (:func:`canal_core.tracker_obstacles.avoided_targets`); each row's
        obstacle status (0 ok, 1 detour, 2 blocked, 3 in_obstacle), or None without a scene.
        Rows whose target the scene moved get a zero feed-forward velocity; a row that is
        done is never blocked (nothing lies ahead of it). Given the rows' ``slots`` (those
        just stepped), a pose the tracker held as suspect (a glitch: see "Plausible steps" in
        :mod:`canal_core.tracker`) is not where the scene is judged from either: its row is
        judged from its held target, so one glitch pose inside an obstacle cannot move it.

        The scene is read once, so a new one set by another thread applies from the next call.
        """
        tables = self.scene
        if tables is None or not len(tables.scene):
            return None
        d = self.geometry.centres.shape[1]
        n = self.geometry.centres.shape[0]
        section = rows[:, d + 2].astype(np.intp)
        where = np.array(positions, dtype=np.float64)
        if slots is not None:
            strikes = self.strikes[np.asarray(slots, dtype=np.intp)]
            held = (strikes > 0) & ((strikes < SUSTAIN) | ~np.isfinite(rows[:, d + 1]))
            where[held] = rows[held, :d]
        target, status = avoided_targets(
            tables, where, rows[:, :d], section, np.minimum(section + self.lookahead, n - 1))
        rows[:, :d] = target
        # A robot that has arrived has nothing ahead for the scene to close: held beside an
        # obstacle over the goal, it ends where a reproduction ends, off its path.
        status[(status == BLOCKED) & (rows[:, d + 4] != 0.0)] = DETOUR
        # The feed-forward velocity is the canal's at the tracker's own target: where the
        # target was moved (a detour, a hold, a way out of an obstacle) it would carry the
        # robot past the corrected target, into what it avoids. It is zero there (a model
        # without velocities keeps NaN).
        moved = status != OK
        if moved.any():
            velocity = rows[:, d + 5 : 2 * d + 5]
            velocity[moved] = np.where(np.isnan(velocity[moved]), np.nan, 0.0)
        return status

    @property
    def has_velocity(self) -> bool:
        """Whether answers carry a feed-forward velocity (the model knows section times)."""
        return self.geometry.section_times is not None

    @property
    def has_orientation(self) -> bool:
        """Whether answers carry an orientation (the model learned orientations)."""
        return self.geometry.orientations is not None

    def _kernel(self) -> Any:
        """The compiled kernel this bank steps with, or None (numpy): circle sections only,
        once compiled, unless the bank was made with ``compiled=False``."""
        return compiled_step_rows() if self._isotropic and self.compiled else None

    def _numpy_step(self, slots: Any, p: FloatArray) -> TrackerBatch:
        b = p.shape[0]
        if b == 1 and (VECTORISE_FROM > 1 or not self._isotropic):
            return self._one(int(slots[0]), p[0])
        slots = np.asarray(slots, dtype=np.intp)
        if self._isotropic and b >= VECTORISE_FROM:
            return self._vectorised(slots, p)
        with np.errstate(all="ignore"):  # far poses overflow; their rows answer outside
            out = self._empty(b)
            if b:
                self._scalar(np.arange(b), slots, p, out)
        return out

    def _compiled_rows(self, kernel: Any, slots: Any, p: FloatArray) -> FloatArray:
        """Every row through the compiled kernel, state read and written in the slot arrays;
        the answers packed (:meth:`step_packed`). The argument types are exactly the
        kernel's one compiled signature (it is called without numba's type dispatch)."""
        g = self.geometry
        b, d = p.shape
        out = np.empty((b, packed_width(d)))
        kernel(*self._kernel_arrays, np.array(slots, dtype=np.intp),
               np.ascontiguousarray(p), self.index, self.eta, self.direction, self.pending,
               self.strikes, self.lookahead, WINDOW, self.replan_tolerance, MAX_PLAN_ETA,
               float(g.done_tolerance), MAX_ADVANCE, MAX_ONWARD, FAR_ETA, SUSTAIN, TUBE_MARGIN,
               out)
        return out

    def _batch_of_rows(self, rows: FloatArray) -> TrackerBatch:
        d = self.geometry.centres.shape[1]
        return TrackerBatch(
            rows[:, :d].copy(), rows[:, d].copy(), rows[:, d + 1].copy(),
            rows[:, d + 2].astype(np.intp), rows[:, d + 3] != 0.0, rows[:, d + 4] != 0.0,
            rows[:, d + 5:2 * d + 5].copy() if self.has_velocity else None,
            rows[:, 2 * d + 5:].copy() if self.has_orientation else None)

    def _rows_of_batch(self, res: TrackerBatch) -> FloatArray:
        b, d = res.target.shape
        rows = np.full((b, packed_width(d)), np.nan)
        rows[:, :d] = res.target
        rows[:, d] = res.progress
        rows[:, d + 1] = res.eta
        rows[:, d + 2] = res.section_index
        rows[:, d + 3] = res.inside
        rows[:, d + 4] = res.done
        if res.velocity is not None:
            rows[:, d + 5:2 * d + 5] = res.velocity
        if res.orientation is not None:
            rows[:, 2 * d + 5:] = res.orientation
        return rows

    def _one(self, slot: int, position: FloatArray) -> TrackerBatch:
        """One row (a drain of one pose, the common case of a keeping-up bridge): the
        scalar step on the slot's state, its answer as 1-row arrays."""
        with np.errstate(all="ignore"):  # far poses overflow; their rows answer outside
            t, st = tracker_step(self.geometry, self.state(slot), position, self.lookahead,
                                 self.replan_tolerance)
        self._keep(slot, st)
        return TrackerBatch(
            t.target[None, :], np.array([t.progress]), np.array([t.eta]),
            np.array([t.section_index], dtype=np.intp), np.array([t.inside]),
            np.array([t.done]), None if t.velocity is None else t.velocity[None, :],
            None if t.orientation is None else t.orientation[None, :].copy())

    def _keep(self, slot: int, st: TrackerState) -> None:
        """A scalar step's new state, written into ``slot``'s arrays."""
        self.index[slot] = st.index
        self.strikes[slot] = st.strikes
        if st.pending is not None:
            self.pending[slot] = st.pending
        if st.eta is None or st.direction is None:
            self.eta[slot] = np.nan
        else:
            self.eta[slot] = st.eta
            self.direction[slot] = st.direction

    def _empty(self, b: int) -> TrackerBatch:
        g = self.geometry
        d = g.centres.shape[1]
        return TrackerBatch(
            np.empty((b, d)), np.empty(b), np.empty(b), np.empty(b, dtype=np.intp),
            np.empty(b, dtype=bool), np.empty(b, dtype=bool),
            None if g.section_times is None else np.empty((b, d)),
            None if g.orientations is None else np.empty((b, 4)))

    def _scalar(self, rows: NDArray[np.intp], slots: NDArray[np.intp], p: FloatArray,
                out: TrackerBatch) -> None:
        for r in rows.tolist():
            slot = int(slots[r])
            t, st = tracker_step(self.geometry, self.state(slot), p[r], self.lookahead,
                                 self.replan_tolerance)
            self._keep(slot, st)
            out.target[r] = t.target
            out.progress[r], out.eta[r], out.section_index[r] = t.progress, t.eta, t.section_index
            out.inside[r], out.done[r] = t.inside, t.done
            if out.velocity is not None and t.velocity is not None:
                out.velocity[r] = t.velocity
            if out.orientation is not None and t.orientation is not None:
                out.orientation[r] = t.orientation

    def _vectorised(self, slots: NDArray[np.intp], p: FloatArray) -> TrackerBatch:
        """Every row in one pass (:func:`batched_tracker_step`), state read and written in
        the slot arrays."""
        (out, self.index[slots], self.eta[slots], self.direction[slots], self.pending[slots],
         self.strikes[slots]) = batched_tracker_step(
            self.geometry, self.index[slots], self.eta[slots], self.direction[slots], p,
            self.lookahead, self.replan_tolerance, self.pending[slots], self.strikes[slots])
        return out
