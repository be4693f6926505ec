"""The pose path's step: every job's tracker stepped, one
:class:`~canal_core.tracker_bank.TrackerBank` pass per model; a stream (re)seeded at the
section its robot is at on a new stream or a restart, at the section and plan it had on a
model switch; a steered stream's plan moved by its person's input.

A model of several routes steps each route's streams in that route's bank: a stream takes the
route whose entry holds its first pose (the nearest entry when none or several do) and keeps
it while the model version stays; on a new version it keeps its route number when the new
model has it, else it is chosen again from its pose; a restart chooses again.

A restart pose the stream's plan takes as a step anyway (near the canal, at most MAX_ADVANCE
sections on) is taken as one: the robot is where the plan has it; after a finished run, one
the canal places more than MAX_ADVANCE sections behind (a new run on a canal that comes
back near its start) is re-located there. A restart is made afresh (re-located
where the pose lies) :data:`RESTART_PAUSE_S` or more after the stream's last pose, or on a
stream with no plan to keep. One glitch pose sent with the flag (at the canal's end, say)
would otherwise re-locate the stream there, and progress never goes back: a restart pose
that jumps is answered ``restart_pending`` with no target and changes nothing, and the
restart is made afresh once SUSTAIN consecutive poses from it on agree (a new run started
at once from another place: SUSTAIN - 1 poses late), or the first pose the plan takes as a
step again is taken as one (the restart pose was a glitch)."""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from canal_core.routes import way_of
from canal_core.steering import STEER_TIMEOUT_S, steered_plan, steering_axes
from canal_core.tracker import (
    MAX_ADVANCE,
    SUSTAIN,
    direction_in_plane,
    located_section,
    plausible_from,
    poses_agree,
    start_section,
)
from canal_protocol import wire

from .answers import Answers
from .models import ModelEntry
from .streams import Job, Stream, end_steered_run, release_slot

_FJSON, _FBIN, _FCDR = wire.FORMAT_JSON, wire.FORMAT_BINARY, wire.FORMAT_CDR
#: Longest time step a steering input is applied over (a stream that paused does not jump).
STEER_MAX_DT = 0.05
#: A restart pose this long after the pose before it is made at once, wherever it is (the
#: robot was moved to another start while nothing was sent); a glitch rides on a running stream.
RESTART_PAUSE_S = 0.5
#: How a restart is made (:meth:`Stepper.restart_of`): re-located where the pose lies, taken
#: as a step of the plan, or not yet.
AFRESH, AS_STEP, PENDING = 0, 1, 2
_RESTART_PENDING = ("expected a restart pose the stream's plan would take as a step, got a "
                    f"jump: nothing moves until {SUSTAIN} poses from the restart pose on "
                    "agree (a new run) or a pose is a step of the plan again (the restart "
                    "pose was a glitch)")


class Stepper(Answers):
    """The pose path's layer that steps the trackers."""

    def step(self, jobs: list[Job]) -> list[tuple[ModelEntry, list[Job], list[list[float]],
                                                  list[int] | None]]:
        """Step every job's tracker, one bank pass per model, the answers as packed rows
        (:meth:`canal_core.tracker_bank.TrackerBank.step_packed`, one ``tolist()`` a pass) and,
        when the skill has a scene, each row's obstacle status (the targets corrected in the
        same pass, :meth:`~canal_core.tracker_bank.TrackerBank.avoid_packed`); jobs
        that cannot be stepped are answered with their error here. The caller silences
        NumPy's overflow warnings (:meth:`batch`, or the worker thread's error state)."""
        by_model: dict[int, tuple[ModelEntry, list[Job], list[int],
                                  list[tuple[float, ...]]]] = {}
        models = self.models.models
        # most drains are one skill's poses: the last job's model and lists are reused
        last_skill = None
        entry: ModelEntry | None = None
        group_jobs: list[Job] = []
        slots: list[int] = []
        positions: list[tuple[float, ...]] = []
        now = time.monotonic()
        for job in jobs:
            st, pose, fmt, _ros = job
            if st.after_gap and id(pose) in st.after_gap:
                st.after_gap.discard(id(pose))
                st.restart_streak = 0  # not consecutive: a pending restart counts afresh
            if st.skill != last_skill:
                entry = models.get(st.skill)
                if entry is None:
                    entry = self.models.entry(st.skill)
                if entry.status != "ok":
                    last_skill = None
                    self.error(st, pose.seq, entry.status, entry.message, fmt)
                    continue
                last_skill = st.skill
                if entry.routes is not None:
                    last_skill = None  # its streams are in several banks: grouped below
                else:
                    group = by_model.get(id(entry))
                    if group is None:
                        group = by_model[id(entry)] = (entry, [], [], [])
                    _, group_jobs, slots, positions = group
            assert entry is not None
            position = pose.position
            if len(position) != entry.dim:
                if fmt == _FCDR and entry.dim == 2:  # a PoseStamped always has z
                    position = position[:2]
                else:
                    self.error(st, pose.seq, "wrong_dimension",
                               f"expected {entry.dim} coordinates for skill {st.skill!r}, "
                               f"got {len(position)}", fmt)
                    continue
            restart = False
            run_from = pose  # where a steered run ended by a route change ends
            if pose.restart or st.restart_at is not None:
                how = self.restart_of(st, position, now)
                if how == PENDING:
                    st.position_at = now  # the stream is not silent: no pause ends the wait
                    if st.restart_streak == 1:
                        st.restart_from = pose
                    self.error(st, pose.seq, "restart_pending", _RESTART_PENDING, fmt)
                    continue
                restart = how == AFRESH
                if restart and st.restart_from is not None:
                    # the new run began at the pose that asked for the restart: the poses
                    # held since are its poses too
                    run_from = st.restart_from
                st.restart_from = None
            tracked = entry
            if entry.routes is not None:
                route, serial = st.route, st.route_serial
                tracked = self._route_of(st, entry, position, restart)
                if st.capture_kind == "steer" and st.route != route and (
                        restart or st.route_reason not in ("kept", "way")):
                    # A steered run is kept as a correction of one route: the poses on the
                    # route left are another route's path, kept apart with that route.
                    end_steered_run(st, route, serial, run_from)
                group = by_model.get(id(tracked))
                if group is None:
                    group = by_model[id(tracked)] = (tracked, [], [], [])
                _, group_jobs, slots, positions = group
            elif st.route is not None:  # a model of one route has no route number to keep
                st.route, st.route_serial = None, -1
            if st.bank is not tracked.bank or st.revision != tracked.revision or restart:
                self._seed(st, tracked, position, restart)
            if st.steer is not None:
                self._steer(st, tracked)
            group_jobs.append(job)
            slots.append(st.slot)
            positions.append(position)
            st.position, st.position_at = position, now
        out = []
        for model, model_jobs, model_slots, model_positions in by_model.values():
            if not model_jobs:
                continue
            bank = model.bank
            assert bank is not None
            p = np.array(model_positions, dtype=np.float64)
            rows = bank.step_packed(model_slots, p)
            # With a scene, the answers go around it (corrected in place, one vectorised pass).
            status = None if bank.scene is None else bank.avoid_packed(rows, p, model_slots)
            out.append((model, model_jobs, rows.tolist(),
                        None if status is None else status.tolist()))
        return out

    @staticmethod
    def restart_of(st: Stream, position: tuple[float, ...], now: float) -> int:
        """How a restart asked for (by this pose or one before it) is made at this
        ``position``: :data:`AFRESH` (re-located where it lies) on a stream with no plan to
        keep (its first pose, or none near the canal yet), :data:`RESTART_PAUSE_S` after the
        stream's last pose, or once SUSTAIN consecutive poses from the restart pose on agree
        (:func:`canal_core.tracker.poses_agree`: a jump confirmed, as a push is);
        :data:`AS_STEP` when the plan takes the pose as a step (near the canal, at most
        MAX_ADVANCE sections on: the robot is where the plan has it, and re-locating it
        at the end of a canal that comes back near its start, say, would be the jump),
        though :data:`AFRESH` after a finished run when the canal places it more than
        MAX_ADVANCE sections behind (that canal's start: a new run); else :data:`PENDING`."""
        previous, bank, jumped = st.position, st.bank, st.restart_at
        how = AFRESH
        if not (previous is None or bank is None or now - st.position_at >= RESTART_PAUSE_S
                or len(previous) != len(position) or math.isnan(bank.eta[st.slot])):
            assert bank is not None
            geometry = bank.geometry
            here = np.array(position, dtype=np.float64)
            index = int(bank.index[st.slot])
            if plausible_from(geometry, index, here):
                # Near where the plan has the robot: a step; but a finished run's restart
                # that the canal places well behind is a new run on a canal that comes back
                # near its start, re-located there. Not before the end: where a canal's
                # turns lie over each other, a pose of the second is placed on the first.
                finished = index >= geometry.centres.shape[0] - 2
                how = AFRESH if finished and \
                    located_section(geometry, here) < index - MAX_ADVANCE else AS_STEP
            else:
                agrees = jumped is not None and len(jumped) == len(position) and poses_agree(
                    geometry, here, np.array(jumped, dtype=np.float64))
                st.restart_streak = st.restart_streak + 1 if agrees else 1
                st.restart_at = position
                if st.restart_streak < SUSTAIN:
                    return PENDING
        st.restart_at, st.restart_streak = None, 0
        return how

    @staticmethod
    def _route_of(st: Stream, entry: ModelEntry, position: tuple[float, ...],
                  restart: bool) -> ModelEntry:
        """The entry (a route's, or the canal of all's) a stream of a model of several
        routes is stepped in: chosen at its first pose or a restart by the route's entry
        (canal_core.routes.Routes.choose); on a new version of the model, the route of its
        way ((R3) of canal_core.routes.way_of, as a kept correction's): the route whose
        directrix passes nearest the one it followed (keeping its number unless another is
        less than half as far), or nearest the robot when it followed none. Routes are
        numbered afresh by each fit: a number kept as it is could be another way."""
        routes = entry.routes
        assert routes is not None
        if st.route_serial != entry.serial or restart:
            old = None if restart or st.revision[0] != entry.created_ns else st.bank
            if old is not None:  # in flight on a new version of the same skill
                followed = st.route is not None and st.route_serial >= 0
                # where the robot was a pose ago: this pose may be a glitch
                at = position if st.position is None else st.position
                way = (old.geometry.centres if followed
                       else np.array(at, dtype=np.float64)[None, :])
                keep = st.route if followed and st.route is not None and st.route < len(routes) else None
                route = way_of(entry.chooser, way, keep)
                st.route_reason = ("nearest" if not followed else "kept" if route == st.route
                                   else "way")
                st.route = route
            else:
                # a skill created again under its name: chosen from where the robot was a
                # pose ago (this pose may be a glitch); a restart, from this pose
                at = position if restart or st.position is None else st.position
                try:
                    choice = entry.chooser.choose(np.array(at, dtype=np.float64))
                    st.route, st.route_reason = choice.route, choice.reason
                except Exception:  # a pose no route can place: the canal of all
                    st.route, st.route_reason = None, "shared"
            st.route_serial = entry.serial
        return entry if st.route is None else routes[st.route]

    def _seed(self, st: Stream, entry: ModelEntry, position: tuple[float, ...],
              restart: bool = False) -> None:
        """The stream's slot in the entry's bank, started at the section the robot is
        located at (a new stream, a restart); on a model switch (a fit, a correction) at
        the section it had reached, with its plan, so a stream in flight is not re-located."""
        st.progress = 0.0  # placed afresh or on another canal: its own progress from here
        carried: tuple[int, float, Any, Any] | None = None
        anchor: tuple[float, ...] | None = None  # where the robot was, placed afresh in flight
        old = st.bank
        if old is not None and st.revision != entry.revision:
            self.counts.switches += 1
            # Placed afresh, as a new stream, on a skill created again under the name (another
            # skill) and on a route chosen from the robot's position (another canal): the
            # share of the canal reached on the old one says nothing there.
            placed_afresh = entry.route != wire.NO_ROUTE and st.route_reason not in ("kept", "way")
            same_skill = st.revision[0] == entry.created_ns
            if not restart and same_skill and not placed_afresh:
                index_old = int(old.index[st.slot])
                carried = (index_old, float(old.eta[st.slot]), old.direction[st.slot].copy(),
                           old.geometry)
            elif not restart:  # another route, or a skill created again under the name
                anchor = st.position
        bank = entry.bank
        assert bank is not None
        if st.bank is not bank:
            release_slot(st)
            st.bank, st.slot = bank, bank.add()
        st.revision = entry.revision
        point = np.array(position, dtype=np.float64)
        if carried is not None:
            index_old, eta, direction, old_geometry = carried
            n, n_old = bank.geometry.centres.shape[0], old_geometry.centres.shape[0]
            # a correction (the same sections of the same route): the plan carries over too
            same_sections = n == n_old and st.route_reason != "way"
            index = index_old
            if not same_sections:  # another fit: the same share of the canal
                index = round(index_old * (n - 1) / max(n_old - 1, 1))
            # ... unless the robot is not there on the new canal (a route that merged with
            # another, a canal that grew at its start): placed afresh, not sent back to it.
            # Where the robot was a pose ago is the new canal's test, not this pose: one
            # glitch right after a refit must not place the stream (at the canal's end, say),
            # it is held as any suspect pose is.
            if plausible_from(bank.geometry, index, point):
                bank.reset(st.slot, index)
                if same_sections:
                    bank.eta[st.slot], bank.direction[st.slot] = eta, direction
                return
            previous = st.position
            if (previous is not None and not math.isnan(eta)
                    and plausible_from(bank.geometry, index, np.array(previous, dtype=np.float64))):
                bank.reset(st.slot, index)
                if not same_sections:
                    direction = direction_in_plane(direction, old_geometry.basis[index_old],
                                                   bank.geometry.basis[index])
                bank.eta[st.slot], bank.direction[st.slot] = eta, direction
                return
        if anchor is not None:
            # placed afresh (another route) from where the robot was a pose ago, with the
            # plan that pose gives: this pose is then a step as any (a glitch is held)
            was = np.array(anchor, dtype=np.float64)
            try:
                located = int(entry.canal.reproduce_detailed(was).section_index)
            except Exception:  # a pose no section brackets: placed from this one below
                located = -1
            if located >= 0 and bank.seed(st.slot, was, located):
                return
        try:
            located = int(entry.canal.reproduce_detailed(point).section_index)
            # a first pose far from the canal (a glitch?) places nothing: from the first
            # section, where the tracker places the stream at its first pose near the canal
            bank.reset(st.slot, start_section(bank.geometry, point, located))
        except Exception:  # a start no section brackets: from the first one
            bank.reset(st.slot, 0)

    def _steer(self, st: Stream, entry: ModelEntry) -> None:
        """Move the stream's plan by its steering input (canal_core.steering, S1); with no
        input for STEER_TIMEOUT_S the stream is back on the plain ratio rule."""
        steer = st.steer
        assert steer is not None and st.bank is not None
        now = time.monotonic()
        u, v, heard = steer
        if now - heard > STEER_TIMEOUT_S:
            st.steer = None
            end_steered_run(st, st.route, st.route_serial)
            return
        bank, slot = st.bank, st.slot
        dt = min(max(now - st.steer_at, 0.0), STEER_MAX_DT)
        st.steer_at = now
        eta = float(bank.eta[slot])
        if math.isnan(eta):  # no plan yet (the first pose of a stream): steer from the next
            return
        if entry.steer_axes is None:
            entry.steer_axes = steering_axes(entry.canal.tangents, entry.canal.basis)
        index = min(int(bank.index[slot]) + bank.lookahead, entry.steer_axes.shape[0] - 1)
        bank.eta[slot], bank.direction[slot] = steered_plan(
            eta, bank.direction[slot], entry.steer_axes[index], u, v, dt)
