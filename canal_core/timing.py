"""The demonstrations' speed profile along the canal, and the timing of reproductions.

The paper's reproduction is time-independent: one point per cross-section, paced by arc
length. Demonstrations that carry time stamps also say *how fast* each part of the motion
goes (slow near a narrow passage, fast in the open). The canal keeps their mean time along
the phase: for each demonstration j (cleaned, see :mod:`canal_core.preprocess`), the time
t_j(u_ji) at which it reaches the phase its aligned sample i comes from: u_ji = i / (N - 1) of
its alignment parameter (normalised arc length, time, index or their blend), or its warp
w_j(i) under a warped alignment (:func:`canal_core.alignment.dtw_parameters`), measured from
its first sample. The section times are their mean,

    tau_i = (1 / n_t) sum_j t_j(u_ji),     i = 0 .. N - 1,

over the n_t demonstrations with time stamps. A reproduction located at fractional section
i0 + alpha and passing through sections i0 + 1 .. N - 1 is given the times
tau(k) - tau(i0 + alpha) (linear in the fractional section), optionally rescaled to a
requested duration, and velocities by finite differences of positions over those times.

Without time stamps a steady logger's sample index still says how the motion is paced, though
not in seconds (:func:`canal_core.clocks.steady_index_clock`). The canal then keeps the mean
share of each demonstration's samples elapsed at each phase,

    pi_i = (1 / n) sum_j k_j(u_ji) / (T_j - 1),     i = 0 .. N - 1,               (P1)

(k_j(u_ji): the sample index at which demonstration j reaches phase u_ji), and a reproduction
asked for a duration is timed by pi scaled to it, as by tau: it spends its time where the
demonstrations spent theirs. Constant speed along the path (:func:`arc_length_times`) is left
for loggers whose index is no clock.

When the demonstrations were aligned by their sample index (one rhythm, T1, on a steady logger,
T2, :mod:`canal_core.clocks`) the sections themselves are placed where the pace reaches equal
shares,

    u'_i = pi^-1(i / (N - 1)),     i = 0 .. N - 1,                                 (P2)

(each demonstration read at its aligned phase there), so a reproduction's positions, one per
section, are evenly spaced in the demonstrations' samples: a robot that streams them at a
fixed rate, with no duration asked, moves with the demonstrations' rhythm. With the arc-length
clock (rhythms that differ) the sections stay at equal phases: the mean pace of rhythms that
differ is a blur, and sections placed by it follow held-out demonstrations less closely
(measured leave-one-out on the generated logs, ``bench/quality.py``).
"""

from __future__ import annotations

import numpy as np

from .alignment import spline_parameter
from .validation import FloatArray


def section_times(
    demos: list[FloatArray], timestamps: list[FloatArray | None], n_samples: int,
    parameters: list[FloatArray | None], warps: FloatArray | None = None,
) -> FloatArray | None:
    """Mean time from the start at which the demonstrations reach each section, shape (N,).

    Parameters
    ----------
    demos : list of arrays, each shape (T_j, D)
        Cleaned demonstrations (no repeats, still ends trimmed).
    timestamps : list of (array, shape (T_j,)) or None
    n_samples : int
        N.
    parameters : list of (array, shape (T_j,)) or None
        What each demonstration was aligned by (:func:`canal_core.clocks.alignment_parameters`;
        None: arc length).
    warps : array, shape (n, N), optional
        The phase each demonstration's aligned sample i came from (a warped alignment,
        :func:`canal_core.alignment.dtw_parameters`); None: u_i = i / (N - 1) for every one.

    Returns
    -------
    tau : array, shape (N,), or None when no demonstration has time stamps
        Non-decreasing, tau[0] = 0.
    """
    u = np.linspace(0.0, 1.0, n_samples)
    rows = []
    for j, (positions, times, parameter) in enumerate(zip(demos, timestamps, parameters, strict=True)):
        if times is None:
            continue
        phase = spline_parameter(positions, parameter)
        rows.append(np.interp(u if warps is None else warps[j], phase, times - times[0]))
    if not rows:
        return None
    tau = np.maximum.accumulate(np.mean(rows, axis=0))
    return np.asarray(tau - tau[0], dtype=np.float64)


def section_pace(
    demos: list[FloatArray], n_samples: int, parameters: list[FloatArray | None],
    warps: FloatArray | None = None,
) -> FloatArray:
    """Mean share of their samples the demonstrations have logged at each section (P1), shape (N,).

    Parameters
    ----------
    demos : list of arrays, each shape (T_j, D)
        Cleaned demonstrations from a steady logger without time stamps.
    n_samples : int
        N.
    parameters : list of (array, shape (T_j,)) or None
        What each demonstration was aligned by, as :func:`section_times`.
    warps : array, shape (n, N), optional
        As :func:`section_times`.

    Returns
    -------
    pi : array, shape (N,)
        Non-decreasing from 0 to 1.
    """
    shares: list[FloatArray | None] = [np.linspace(0.0, 1.0, d.shape[0]) for d in demos]
    pace = section_times(demos, shares, n_samples, parameters, warps)
    assert pace is not None  # every demonstration has its shares
    return np.asarray(pace / max(float(pace[-1]), 1e-300), dtype=np.float64)


def paced_phases(pace: FloatArray) -> FloatArray:
    """Phases u'_i, shape (N,), at which ``pace`` (N,), given at equal phases, reaches equal
    shares i / (N - 1) (P2); 0 first and 1 last."""
    n = pace.shape[0]
    grid = np.linspace(0.0, 1.0, n)
    # A flat stretch of the pace (a demonstration at rest) has no single phase: the ramp of
    # 1e-9 keeps the inverse a function without moving it measurably.
    share = np.maximum.accumulate(pace / max(float(pace[-1]), 1e-300)) + 1e-9 * grid
    phases = np.interp(grid, share / share[-1], grid)
    phases[0], phases[-1] = 0.0, 1.0
    return np.asarray(phases, dtype=np.float64)


def reproduction_times(
    tau: FloatArray, start_index: int, start_alpha: float, n_points: int
) -> FloatArray:
    """Times, shape (n_points,), of a reproduction: its start, then sections N - n_points + 1 .. N - 1.

    Parameters
    ----------
    tau : array, shape (N,)
        Section times (:func:`section_times`).
    start_index, start_alpha : int, float
        Where the start was located (between sections i and i + 1).
    n_points : int
        Length of the reproduction (start included).
    """
    n = tau.shape[0]
    t0 = float(np.interp(start_index + start_alpha, np.arange(n), tau))
    path = tau[n - (n_points - 1) :] - t0
    times = np.concatenate([[0.0], path])
    return strictly_increasing(times)


def arc_length_times(positions: FloatArray, duration: float) -> FloatArray:
    """Times, shape (T,), at constant speed along ``positions`` (T, D), ending at ``duration``."""
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(steps)])
    times = s * (duration / s[-1]) if s[-1] > 0.0 else np.linspace(0.0, duration, positions.shape[0])
    return strictly_increasing(times)


def strictly_increasing(times: FloatArray) -> FloatArray:
    """``times`` made strictly increasing by the least nudge (1e-9 of the span per step)."""
    if times.shape[0] < 2:
        return times.astype(np.float64)
    span = max(float(times[-1] - times[0]), 1.0)
    eps = 1e-9 * span
    steps = np.maximum(np.diff(times), eps)
    return np.asarray(np.concatenate([[times[0]], times[0] + np.cumsum(steps)]), dtype=np.float64)


def top_speed(profile: FloatArray, steps: FloatArray) -> float:
    """The demonstrations' fastest pace along the canal: the largest step a demonstration
    takes into a section over the time the section takes, max_k steps_k / (tau_k - tau_{k-1})
    (in the profile's units per second, or per share of the motion), over the sections that
    take time.

    Parameters
    ----------
    profile : array, shape (N,)
        Section times tau (or the pace pi of (P1)).
    steps : array, shape (N,)
        The demonstrations' largest step into or out of each section (``Canal.section_steps``).

    Returns
    -------
    speed : float
        inf when no section takes time (nothing to limit by).
    """
    dt = np.diff(profile)
    moving = dt > 0.0
    if not moving.any():
        return float("inf")
    return float(np.max(steps[1:][moving] / dt[moving]))


def speed_limited_times(times: FloatArray, positions: FloatArray, speed: float) -> FloatArray:
    """``times`` (T,) stretched where a step of ``positions`` (T, D) would go faster than
    ``speed``: each step takes max(its time, its length / speed), the rest follows as much later.
    """
    if times.shape[0] < 2 or not np.isfinite(speed) or speed <= 0.0:
        return times
    steps = np.sqrt(((positions[1:] - positions[:-1]) ** 2).sum(axis=1))
    dt = np.maximum(np.diff(times), steps / speed)
    return np.asarray(np.concatenate([times[:1], times[0] + np.cumsum(dt)]), dtype=np.float64)


def rescaled_times(times: FloatArray, duration: float) -> FloatArray:
    """``times`` (T,) from 0, stretched so the last is ``duration``."""
    if times.shape[0] < 2 or times[-1] <= 0.0:
        return np.linspace(0.0, duration, times.shape[0])
    return np.asarray(times * (duration / times[-1]), dtype=np.float64)


def finite_velocities(positions: FloatArray, times: FloatArray) -> FloatArray:
    """Velocities, shape (T, D), by second-order finite differences over uneven ``times`` (T,).

    The last sample's velocity is zero: the reproduction ends where the demonstrations
    stopped (their still tails were trimmed, so one-sided differences there would report
    the last moving speed as the arrival speed).
    """
    if positions.shape[0] < 2:
        return np.zeros_like(positions)
    velocity = np.gradient(positions, times, axis=0, edge_order=1)
    velocity[-1] = 0.0
    return np.asarray(velocity, dtype=np.float64)
