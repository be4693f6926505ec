"""The live tracker step compiled: every row of a :class:`~canal_core.tracker_bank.TrackerBank`
call in one machine-code loop (numba), for circle-section canals.

Why compiled: a live bridge steps one to a few dozen rows per call, and the vectorised numpy
pass (:func:`canal_core.tracker_batch.batched_tracker_step`) costs about 50 numpy calls whatever
the batch size: 30-60 us a call, most of a 1 kHz robot's budget on one core shared with the
middleware. Here each row costs a few dozen floating-point operations and a call about a
microsecond, so a one-robot drain and a sixteen-robot drain both cost next to nothing.

The rules are :func:`canal_core.tracker.tracker_step`'s, written out row by row in the same
order (window search, forward search when pushed ahead, the located pair's interpolated
in-plane offset and reach, the plan kept within ``replan_tolerance``, the ends, the target,
feed-forward velocity and orientation); ``tests/core/test_core_tracker_equivalence.py``
compares every row with the scalar step on random canals and walks (floats up to the last
bits of a reordered sum).

numba is optional: :func:`compiled_step_rows` returns None until :func:`compile_step_rows`
has compiled (or loaded from numba's on-disk cache) the kernel, and when numba is not
installed, so a caller falls back to numpy and never waits for a compiler on a live thread.
"""

from __future__ import annotations

import importlib.util
import math
import threading
from collections.abc import Callable
from typing import Any

import numpy as np

_lock = threading.Lock()
_compiled: Any = None  # step_rows compiled: its entry point (or dispatcher), set once


def step_rows(centres: Any, tangents: Any, offsets: Any, basis: Any, radius: Any, curvature: Any,
              times: Any, orientations: Any, default_direction: Any, slots: Any, p: Any,
              index: Any, eta: Any, direction: Any, pending: Any, strikes: Any,
              lookahead: int, window: int, tolerance: float, max_plan_eta: float,
              done_tolerance: float, max_advance: int, max_onward: int, far_eta: float,
              sustain: int, tube_margin: float, out: Any) -> None:
    """Step the trackers of ``slots`` (B,) at live positions ``p`` (B, D) in place, the
    answers packed in the rows of ``out`` (see :func:`packed_width`).

    Parameters
    ----------
    centres, tangents : array, shape (N, D)
    offsets : array, shape (N,)
        t_i . c_i.
    basis : array, shape (N, D - 1, D)
    radius : array, shape (N,)
    curvature : array, shape (N, D - 1)
        b_k of the tube condition (:mod:`canal_core.tube`, F1): a planned ratio is capped
        where its product with r_k and the plan's direction exceeds ``tube_margin``.
    times : array, shape (N,) or (0,)
        Mean time to each section; empty: no feed-forward velocity.
    orientations : array, shape (N, 4) or (0, 4)
        Section mean orientations; empty: none.
    default_direction : array, shape (D - 1,)
        The in-plane direction of a position on the directrix.
    slots : array of int, shape (B,)
        Distinct rows of the state arrays.
    p : array, shape (B, D)
    index : array of int, shape (S,)
    eta : array, shape (S,)
        Planned ratio per slot, NaN: no plan. Updated in place, as ``index`` and
        ``direction``.
    direction : array, shape (S, D - 1)
    pending : array, shape (S, D)
    strikes : array of int, shape (S,)
        Each slot's last suspect pose and the streak's length (0: none;
        :class:`canal_core.tracker.TrackerState`); updated in place.
    lookahead : int
        >= 1.
    window : int
        Sections searched ahead of the last one reached.
    tolerance, max_plan_eta, done_tolerance : float
        The replan tolerance (a fraction of the reach), the largest planned ratio and the
        distance to the last plane that counts as reached.
    max_advance, max_onward, far_eta, sustain
        The plausible-step rule's :data:`~canal_core.tracker.MAX_ADVANCE`,
        :data:`~canal_core.tracker.MAX_ONWARD`, :data:`~canal_core.tracker.FAR_ETA` and
        :data:`~canal_core.tracker.SUSTAIN`.
    tube_margin : float
        :data:`~canal_core.tube.TUBE_MARGIN` (an argument, not a global: numba's cache would
        keep a global's value from the compile).
    out : array, shape (B, 2 D + 9)
        Row b: target (D), progress, live eta, section index, inside (1.0 or 0.0), done
        (1.0 or 0.0), feed-forward velocity (D; NaN when ``times`` is empty), orientation (4;
        NaN when ``orientations`` is empty). One float row per answer, so that a caller
        reads a call's answers with one ``tolist()``.
    """
    n = centres.shape[0]
    d = centres.shape[1]
    k = basis.shape[1]
    q = np.empty(k)
    plan = np.empty(k)
    for r in range(slots.shape[0]):
        slot = slots[r]
        last = index[slot]
        lo = max(last - 1, 0)
        hi = min(last + window, n - 1)
        # the window: the first pair of planes the position lies between
        found = -1
        # signed plane distances t_i . x - t_i . c_i, summed as a dot product is
        before = -offsets[lo]
        dot = 0.0
        for j in range(d):
            dot += tangents[lo, j] * p[r, j]
        before += dot
        for s in range(lo, hi):
            dot = 0.0
            for j in range(d):
                dot += tangents[s + 1, j] * p[r, j]
            after = dot - offsets[s + 1]
            if before == 0.0 or (before > 0.0) != (after > 0.0):
                found = s
                break
            before = after
        if found >= 0:
            at = found
        elif before > 0.0 and hi < n - 1:
            # pushed ahead of the window: the bracketing pair ahead nearest the robot (the
            # first plane crossed could be a later turn of a helix); none: the last pair
            at = n - 2
            best = math.inf
            seen = False
            for s in range(hi, n - 1):
                dot = 0.0
                for j in range(d):
                    dot += tangents[s + 1, j] * p[r, j]
                after = dot - offsets[s + 1]
                if before == 0.0 or (before > 0.0) != (after > 0.0):
                    gap = 0.0
                    for j in range(d):
                        e = centres[s, j] - p[r, j]
                        gap += e * e
                    gap = math.sqrt(gap)
                    if not seen or gap < best:
                        at, best, seen = s, gap, True
                before = after
        elif before > 0.0:  # past the last plane
            at = n - 2
        else:  # behind the window: hold, never go back
            at = lo
            found = lo
        if found >= 0:
            # as tracker._passed_planes: the furthest plane up to lookahead past the first
            # crossing or the section reached that the position is on or in front of
            for s in range(min(max(found, last) + max(lookahead, 1), hi), found, -1):
                dot = 0.0
                for j in range(d):
                    dot += tangents[s, j] * p[r, j]
                if dot - offsets[s] >= -done_tolerance:
                    at = s
                    break
        at = max(min(at, n - 2), 0)
        d0 = 0.0
        d1 = 0.0
        for j in range(d):
            d0 += tangents[at, j] * p[r, j]
            d1 += tangents[at + 1, j] * p[r, j]
        d0 -= offsets[at]
        d1 -= offsets[at + 1]
        alpha = 0.0
        if d0 != d1:
            alpha = d0 / (d0 - d1)
            if 0.0 > alpha:
                alpha = 0.0
            if 1.0 < alpha:
                alpha = 1.0
        # the in-plane offset interpolated between the pair (the ratio rule, paper Section 4.2)
        norm2 = 0.0
        for m in range(k):
            q0 = 0.0
            q1 = 0.0
            for j in range(d):
                q0 += basis[at, m, j] * (p[r, j] - centres[at, j])
                q1 += basis[at + 1, m, j] * (p[r, j] - centres[at + 1, j])
            q[m] = (1.0 - alpha) * q0 + alpha * q1
            norm2 += q[m] * q[m]
        norm = math.sqrt(norm2)
        reach = (1.0 - alpha) * radius[at] + alpha * radius[at + 1]
        if reach > 0.0:
            live_eta = norm / reach
        else:
            live_eta = math.inf if norm > 0.0 else 0.0
        # plausible steps (canal_core.tracker): a suspect pose of a stream with a plan is
        # held, one with no plan is answered as located and leaves the stream unplaced
        old = eta[slot]
        planned = not math.isnan(old)
        unplaced = False
        held = False
        streak = 0
        far = not live_eta <= far_eta or d0 < -far_eta * reach or d1 > far_eta * reach
        if far or (planned and at - last > max_advance):
            if not planned:
                unplaced = True
            else:
                streak = 1
                if strikes[slot] > 0:
                    gap = 0.0
                    onward = 0.0
                    for j in range(d):
                        e = p[r, j] - pending[slot, j]
                        gap += e * e
                        onward += tangents[at, j] * e
                    across = gap - onward * onward
                    back = max(at - max_onward, 0)
                    most = 0.0
                    for j in range(d):
                        e = centres[at, j] - centres[back, j]
                        most += e * e
                    if (not far and 0.0 < onward and onward * onward <= most
                            and across <= (far_eta * reach) ** 2) \
                            or math.sqrt(gap) <= far_eta * reach:
                        streak = min(strikes[slot] + 1, sustain)
                held = streak < sustain or not math.isfinite(live_eta)
        if held:
            at = max(min(last, n - 2), 0)
            alpha = 0.0
        # the plan: kept while the live position is near it, else the live eta and direction
        keep = False
        if held:
            keep = True
        elif planned:
            dev = 0.0
            for m in range(k):
                e = q[m] - (old * reach) * direction[slot, m]
                dev += e * e
            keep = math.sqrt(dev) <= tolerance * reach
        if keep:
            plan_eta = old
            for m in range(k):
                plan[m] = direction[slot, m]
        else:
            plan_eta = max_plan_eta if max_plan_eta < live_eta else live_eta
            for m in range(k):
                plan[m] = q[m] / norm if norm > 0.0 else default_direction[m]
        inside = live_eta <= 1.0 + 1e-9 and not (at == 0 and d0 < 0.0) \
            and not (at == n - 2 and d1 > done_tolerance) and not held
        done = at >= n - 2 and d1 >= -done_tolerance and not held
        aim = min(max(at, last) + lookahead, n - 1)  # from the section reached (as tracker_step)
        # the tube condition (F1) on the target's section and the next (the feed-forward's):
        # their ratios are capped, not the plan's
        after = min(aim + 1, n - 1)
        turn = 0.0
        turn_after = 0.0
        for m in range(k):
            turn += plan[m] * curvature[aim, m]
            turn_after += plan[m] * curvature[after, m]
        turn *= radius[aim]
        turn_after *= radius[after]
        scale = (plan_eta if plan_eta * turn <= tube_margin else tube_margin / turn) * radius[aim]
        for j in range(d):
            s_j = 0.0
            for m in range(k):
                s_j += plan[m] * basis[aim, m, j]
            out[r, j] = centres[aim, j] + scale * s_j
        out[r, d] = 1.0 if done else (at + alpha) / max(n - 1, 1)
        out[r, d + 1] = live_eta
        out[r, d + 2] = at
        out[r, d + 3] = 1.0 if inside else 0.0
        out[r, d + 4] = 1.0 if done else 0.0
        v0 = d + 5
        o0 = 2 * d + 5
        if times.shape[0] == 0:
            for j in range(d):
                out[r, v0 + j] = math.nan
        else:
            # feed-forward: from the target to the planned point on the next section
            nxt = aim + 1
            dt = times[nxt] - times[aim] if nxt < n else 0.0
            if nxt >= n or dt <= 0.0:
                for j in range(d):
                    out[r, v0 + j] = 0.0
            else:
                ahead_scale = (plan_eta if plan_eta * turn_after <= tube_margin
                               else tube_margin / turn_after) * radius[nxt]
                for j in range(d):
                    s_j = 0.0
                    for m in range(k):
                        s_j += plan[m] * basis[nxt, m, j]
                    out[r, v0 + j] = (centres[nxt, j] + ahead_scale * s_j - out[r, j]) / dt
        if orientations.shape[0] == 0:
            for j in range(4):
                out[r, o0 + j] = math.nan
        else:
            for j in range(4):
                out[r, o0 + j] = orientations[aim, j]
        if not unplaced:
            # a followed displacement stays followed while its poses agree
            strikes[slot] = streak
            if streak > 0:
                for j in range(d):
                    pending[slot, j] = p[r, j]
        if not held and not unplaced:
            index[slot] = max(last, at)
            eta[slot] = plan_eta
            for m in range(k):
                direction[slot, m] = plan[m]


def packed_width(d: int) -> int:
    """Columns of a :func:`step_rows` answer row for a D-dimensional canal: target (D),
    progress, eta, section, inside, done, velocity (D), orientation (4)."""
    return 2 * d + 9


def numba_available() -> bool:
    """Whether numba is installed (the compiled step can be built)."""
    return importlib.util.find_spec("numba") is not None


def compiled_step_rows() -> Callable[..., None] | None:
    """The compiled :func:`step_rows`, or None while it is not compiled (or numba is
    missing): a caller then takes the numpy pass instead of waiting for the compiler.

    It is the compiled signature's entry point, not numba's dispatcher: the dispatcher
    types every argument on every call (about 1 us hot, 5 us cold of a one-pose drain's
    budget), so the caller must pass exactly the types :func:`_run_once` passes:
    C-contiguous float64 arrays (``slots`` and ``index`` intp), Python int and float
    scalars."""
    return _compiled  # type: ignore[no-any-return]


def compile_step_rows() -> Callable[..., None] | None:
    """Compile :func:`step_rows` (numba's on-disk cache makes later processes load it in
    about 0.1 s; importing numba takes about 1 s, the first compile a few seconds) so that
    :func:`compiled_step_rows` returns it. None when numba is not installed. Safe from any
    thread, any number of times."""
    global _compiled
    if _compiled is not None or not numba_available():
        return _compiled  # type: ignore[no-any-return]
    with _lock:
        if _compiled is None:
            import numba

            kernel = numba.njit(cache=True, nogil=True)(step_rows)
            _run_once(kernel)  # the one signature every bank passes
            overloads = getattr(kernel, "overloads", {})
            signatures = list(overloads)
            entry = getattr(overloads[signatures[0]], "entry_point", None) \
                if len(signatures) == 1 else None
            _compiled = kernel if entry is None else entry
    return _compiled  # type: ignore[no-any-return]


def _run_once(kernel: Callable[..., None]) -> None:
    """One call on a tiny canal: the argument types every bank passes (C-contiguous float64
    and intp arrays, Python int and float scalars), so the live path never compiles another
    signature."""
    n, d = 3, 3
    centres = np.zeros((n, d))
    centres[:, 0] = np.arange(n)
    tangents = np.zeros((n, d))
    tangents[:, 0] = 1.0
    basis = np.zeros((n, d - 1, d))
    basis[:, 0, 1] = basis[:, 1, 2] = 1.0
    kernel(centres, tangents, centres[:, 0].copy(), basis, np.ones(n), np.zeros((n, d - 1)), np.zeros(0),
           np.zeros((0, 4)), np.array([1.0, 0.0]), np.zeros(1, dtype=np.intp),
           np.array([[0.5, 0.1, 0.0]]), np.zeros(1, dtype=np.intp), np.full(1, np.nan),
           np.zeros((1, d - 1)), np.zeros((1, d)), np.zeros(1, dtype=np.intp),
           1, 16, 0.25, 0.9, 1e-9, 8, 32, 3.0, 4, 0.95, np.empty((1, packed_width(d))))


__all__ = ["compile_step_rows", "compiled_step_rows", "numba_available", "packed_width",
           "step_rows"]
