"""Which clock aligns the demonstrations: their time stamps, their sample index, or arc length.

Sample i of the directrix is the mean of every demonstration at the same phase u_i of a clock.
Aligning by *time* pairs the points the demonstrators reached after the same share of their
motion; aligning by *arc length* pairs the points after the same share of their path. Time is
the better pairing when the demonstrators kept one rhythm (a pause or a slow part at the same
place each time), arc length when their speed profiles differ (one hurries early, the next
late): then equal times are different places.

Timing test (consistent rhythm). For each demonstration j (cleaned), tau_j(u) is the share of
its duration elapsed when it has covered the share u of its path. The demonstrations keep one
rhythm when, on average over u in [0, 1],

    sigma_tau = mean_u std_j tau_j(u)  <=  TIMING_SPREAD                          (T1)

(0.06: a tenth of the motion is 2.4 sigma). Measured on leave-one-out folds (BENCHMARKS.md): the
RAIL tasks, UR5e and LASA have sigma_tau 0.02-0.05 and follow held-out demos closer aligned
by time; the generated logs, whose speed profiles are warped by up to a quarter, have 0.08 and
follow them closer by arc length.

Without time stamps the sample index is a clock only when the logger's rate was steady at the
scale the alignment pairs phases: the warp alignment matches the demonstrations on
``DTW_SAMPLES`` (64) samples, so each demonstration is judged on windows of w_j = ceil((T_j - 1) / 64)
samples. For a smooth motion logged at a steady rate, consecutive windows cover nearly equal
lengths; a logger that writes in bursts or stalls makes them jump. The index is taken as a clock
when

    median_k |log(L_{k+1} / L_k)|  <=  STEADY_JITTER                              (T2)

(L_k: the chord of window k) over the windows longer than 5 % of the median window (starts and
stops, where speed goes to zero, say nothing), for every demonstration. 0.45: steady logs measure
0.03-0.43 here, and a rate that changes fourfold from one window to the next measures 1.4.
Single rows are not judged: a logger that polls a slower pose source holds each pose for two or
three rows (the RAIL logs: 100 Hz rows, 40 Hz poses) and its row-to-row steps jump from zero to
twice the mean, yet its index is a clock. Rows dropped at random make the windows noisy (two
thirds of 400 rows dropped: 0.32-0.63 over 20 draws, about the threshold). A rate that drifts
slowly, or stalls once, is not seen by (T2); (T1) below sees it when the demonstrations differ.
An index clock aligns, but it is not seconds: a model aligned by it has no section times, and
its reproductions no duration, unless one is asked for (then the index paces them, P1 of
:mod:`canal_core.timing`).

Blended clock (the default when the rhythm is consistent). Measured leave-one-out (BENCHMARKS.md)
pure time beats arc length on some tasks (RAIL pressing and pushing, UR5e) and loses on others
(RAIL reaching and writing) with the same sigma_tau; the mean of the two shares,

    phi_j = (tau_j + s_j) / 2                                                     (B1)

(tau_j: the share of the duration, or of the samples, elapsed; s_j: the share of the path
covered; both rise from 0 to 1, so phi_j does) beat both on the sum over those tasks. "auto"
therefore aligns by ``time+arc`` (stamped) or ``index+arc`` (a steady logger) when (T1) holds.
"""

from __future__ import annotations

from typing import Literal, cast, get_args

import numpy as np

from .alignment import DTW_SAMPLES, normalised_arc_length
from .validation import FloatArray

#: The clocks a fit may align by: the demos' time stamps, their sample index, arc length, or
#: the mean of the time (or index) share and the arc-length share (B1).
Clock = Literal["time", "index", "arc", "time+arc", "index+arc"]
CLOCKS: tuple[Clock, ...] = get_args(Clock)
#: What a fit may be asked for: one of the clocks, or "auto" (the tests below).
TimingChoice = Literal["auto", "time", "index", "arc", "time+arc", "index+arc"]
TIMINGS: tuple[TimingChoice, ...] = get_args(TimingChoice)
#: (T1): largest mean spread of the demonstrations' elapsed-time share at equal path share.
TIMING_SPREAD = 0.06
#: (T2): largest median |log| ratio of consecutive window chords of a steady logger.
STEADY_JITTER = 0.45
#: Windows shorter than this share of the median window are not judged by (T2).
MOVING_STEP = 0.05
#: Phases at which (T1) compares the demonstrations.
PHASES = 101


def jitter_window(n_samples: int) -> int:
    """Samples per window of (T2) for a demo of ``n_samples``: 1/64 of it, at least one step."""
    return max(1, -(-(int(n_samples) - 1) // DTW_SAMPLES))


def step_jitter(positions: FloatArray, window: int = 1) -> float:
    """median |log(L_{k+1} / L_k)| over consecutive moving windows of a demo (T2).

    Parameters
    ----------
    positions : array, shape (T, D)
    window : int
        Samples per window: L_k is the chord from sample k * window to (k + 1) * window.
    """
    last = (positions.shape[0] - 1) // window * window
    steps = np.linalg.norm(np.diff(positions[: last + 1 : window], axis=0), axis=1)
    if steps.size < 2:
        return float("inf")
    moving = steps > MOVING_STEP * float(np.median(steps[steps > 0.0])) if np.any(steps > 0.0) else steps > 0.0
    pair = moving[:-1] & moving[1:]
    if not np.any(pair):
        return float("inf")
    return float(np.median(np.abs(np.log(steps[1:][pair] / steps[:-1][pair]))))


def steady_index_clock(demos: list[FloatArray]) -> bool:
    """Whether every demo's sample index is a fair clock at the alignment's scale (T2)."""
    return all(step_jitter(d, jitter_window(d.shape[0])) <= STEADY_JITTER for d in demos)


def timing_spread(demos: list[FloatArray], clocks: list[FloatArray]) -> float:
    """sigma_tau of (T1): mean over path shares of the spread of elapsed-time shares.

    Parameters
    ----------
    demos : list of arrays, each shape (T_j, D)
    clocks : list of arrays, each shape (T_j,)
        Increasing clock readings per sample (time stamps, or the index).
    """
    u = np.linspace(0.0, 1.0, PHASES)
    rows = []
    for positions, clock in zip(demos, clocks, strict=True):
        share = (clock - clock[0]) / max(float(clock[-1] - clock[0]), 1e-300)
        rows.append(np.interp(u, normalised_arc_length(positions), share))
    return float(np.mean(np.std(rows, axis=0)))


def chosen_clock(
    demos: list[FloatArray], timestamps: list[FloatArray | None], timing: TimingChoice = "auto",
    steady: bool | None = None,
) -> Clock:
    """The clock a fit aligns by.

    A clock with "time" needs every demo stamped (else arc length); one with "index" is
    taken as asked when no demo is stamped (stamped demos have a better clock: "time");
    "arc" always. "auto" takes the time stamps when every demo has them, else the index when
    no demo has them and every logger was steady (T2), and keeps that clock, blended with arc
    length (B1), only when the demonstrations' rhythm is consistent by it (T1); otherwise arc
    length. ``steady``: (T2) when the caller has it already (None: judged here).
    """
    stamped = all(t is not None for t in timestamps)
    if timing == "time":
        return "time" if stamped else "arc"
    if timing in ("index", "index+arc"):
        return cast(Clock, timing.replace("index", "time")) if stamped else cast(Clock, timing)
    if timing == "time+arc":
        return "time+arc" if stamped else "arc"
    if timing != "auto":
        return cast(Clock, timing)
    if stamped:
        clocks = [np.asarray(t, dtype=np.float64) for t in timestamps if t is not None]
        candidate: Clock = "time+arc"
    elif all(t is None for t in timestamps) and (steady_index_clock(demos) if steady is None else steady):
        clocks = [np.arange(d.shape[0], dtype=np.float64) for d in demos]
        candidate = "index+arc"
    else:
        return "arc"
    return candidate if timing_spread(demos, clocks) <= TIMING_SPREAD else "arc"


def alignment_parameters(
    demos: list[FloatArray], timestamps: list[FloatArray | None], clock: Clock
) -> list[FloatArray | None]:
    """Per demo, the increasing parameter its spline is aligned by (None: arc length).

    Time stamps for "time", the sample index for "index", (B1) for the blends.
    """
    if clock == "arc":
        return [None] * len(demos)
    out: list[FloatArray | None] = []
    for positions, stamps in zip(demos, timestamps, strict=True):
        reading = (np.arange(positions.shape[0], dtype=np.float64) if clock.startswith("index")
                   else np.asarray(stamps, dtype=np.float64))
        if not clock.endswith("+arc"):
            out.append(reading)
            continue
        share = (reading - reading[0]) / max(float(reading[-1] - reading[0]), 1e-300)
        out.append(0.5 * (share + normalised_arc_length(positions)))
    return out
