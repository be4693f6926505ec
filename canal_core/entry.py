"""Entering the canal from a start outside it, the way the demonstrations' own starts converge.

A demonstration by the next person usually starts outside the canal of the others (the canal
is the envelope of what was shown; the next start is a new sample). The paper assumes a start
inside. The entry blend of :func:`canal_core.reproduce.path_ratios` takes an outside start
(ratio eta > 1) to the wall over an entry length L_in,

    eta_k = min(eta f_k, 1 + (eta - 1) (1 - S((s_k - s_0) / L_in)))               (E1)

(f_k: the learned persistence, S: smootherstep). A fixed L_in (a tenth of the canal) enters
at the same pace whatever the demonstrations did. The learned entry length is where the
demonstrations' own start offsets have half faded, from the start's section on:

    L_in = s_k* - s_0,   k* = the first section with f_k <= 1/2 or R_k(u) <= R_0(u) / 2   (E2)

in units of the canal's width (f_k, the demonstrations' ratios regressed on their start
ratios) or in absolute terms (R_k(u), the boundary distance along the start's direction u:
a canal that narrows is demonstrations converging). When neither happens (demonstrations
that keep their offsets in a canal that keeps its width) the fixed blend is used.

A canal of one demonstration has no demonstrations converging to enter by: it is reproduced
by (L2) of :mod:`canal_core.lone`. Once the path is inside it stays inside, as the live
tracker's rules assume:

    eta_k <- min(eta_k, 1)   for every k >= the first k with eta_k <= 1                 (E3)

A start *behind* the first plane (the canal's extruded head holds it, or it lies farther
back) has no section of its own: the ratio rule's first point lies on section 1, one
section's time away. The straight step there is the distance behind, which can be many times
the demonstrations' largest step. The reproduction approaches that point along the straight
line instead, at the pace the demonstrations set off with: with d the distance from the start
to the first point and s_i the directrix's arc length, approach point i (i = 1 .. m - 1) lies
at the share

    a_i = s_i / s_m,   m = the section whose s_m is nearest to d (1 .. N - 1)            (E4)

of that line, at the time section i has, and the ratio rule's path follows m - 1 sections'
time later. The steps are the directrix's own first steps, within a factor 1.5 (the nearest
count of them): from rest, as the demonstrations started, never one jump. A start a little
behind the plane, whose first step is about the directrix's, gets none (m = 1).

A start *beside* the canal, outside it, can be left far from the path's first point too:
where the tube's cap (F1 of :mod:`canal_core.tube`) cuts the entry short, the points before
the cut come down to it at the demonstrations' pace, and the distance left is at the start.
When it is longer than the demonstrations' largest step there, the approach is the straight
line in equal steps of at most that step, one section's time each:

    a_i = i / m,   m = ceil(d / step)                                                  (E5)
"""

from __future__ import annotations

import numpy as np

from .validation import FloatArray

#: (E2): the share of the start offset left where the demonstrations' offsets count as faded.
HALF_FADED = 0.5


def inside_stays_inside(ratios: FloatArray) -> FloatArray:
    """Ratios (K,) with every one after the first ratio <= 1 clamped to at most 1 (E3)."""
    entered = np.flatnonzero(ratios <= 1.0)
    if entered.size == 0 or entered[0] == ratios.size - 1:
        return ratios
    out = np.array(ratios, dtype=np.float64)
    out[entered[0]:] = np.minimum(out[entered[0]:], 1.0)
    return out


def approach_shares(arclength: FloatArray, distance: float) -> FloatArray:
    """a_1 .. a_m of (E4), shape (m,), ending at 1: where a start behind the first plane
    passes on its straight line to the ratio rule's first point, ``distance`` away.

    Parameters
    ----------
    arclength : array, shape (N,)
        The directrix's arc length at its sections (from 0).
    distance : float
        d, from the start to the first point.

    Returns
    -------
    shares : array, shape (m,)
        m = 1 (just [1.0]) when ``distance`` is nearer to the directrix's first step than to
        its first two; a start farther behind than the whole directrix is long takes all its
        steps, stretched.
    """
    m = 1 + int(np.argmin(np.abs(arclength[1:] - distance)))
    shares = arclength[1 : m + 1] / max(float(arclength[m]), 1e-300)
    shares[-1] = 1.0
    return np.asarray(shares, dtype=np.float64)


def paced_approach_shares(distance: float, step: float, most: int) -> FloatArray:
    """a_1 .. a_m of (E5), shape (m,), ending at 1: where a start outside passes on its
    straight line to the ratio rule's first point, ``distance`` away, in steps of at most
    ``step`` (the demonstrations' largest around that point): a_i = i / m, m = ceil(d / step).

    Parameters
    ----------
    distance : float
        d, from the start to the first point.
    step : float
        The largest step a demonstration takes there (``Canal.section_steps``).
    most : int
        At most this many (the canal's sections): a start farther away takes longer steps,
        and the reproduction's times give each the time it needs.

    Returns
    -------
    shares : array, shape (m,)
        Just [1.0] when ``distance`` is at most ``step`` (or ``step`` is 0).
    """
    m = min(int(np.ceil(distance / step)), max(most, 1)) if step > 0.0 and distance > step else 1
    return np.asarray(np.arange(1, m + 1, dtype=np.float64) / m, dtype=np.float64)


def entry_fraction(
    arclength: FloatArray,
    start_arclength: float,
    persistence: FloatArray | None,
    reach: FloatArray,
    fallback: float,
) -> float:
    """L_in of (E2) as a fraction of the canal's length.

    Parameters
    ----------
    arclength : array, shape (K,)
        Arc length of the directrix at the remaining sections (the last is the canal's length).
    start_arclength : float
        s_0.
    persistence : array, shape (K,), or None
        f_k on those sections (None: the demonstrations do not spread along u).
    reach : array, shape (K + 1,)
        R_k(u) on the start's section and the remaining ones.
    fallback : float
        The fraction used when the demonstrations' offsets do not fade.
    """
    total = float(arclength[-1]) if arclength.size else 0.0
    if total <= 0.0 or arclength.size == 0:
        return fallback
    faded = reach[1:] <= HALF_FADED * reach[0]
    if persistence is not None:
        faded = faded | (persistence <= HALF_FADED)
    hit = np.flatnonzero(faded)
    if hit.size == 0:
        return fallback
    return float(max(arclength[hit[0]] - start_arclength, 0.0)) / total
