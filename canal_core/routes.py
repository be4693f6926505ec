"""Several routes: demonstrations that go different ways learn one canal per route.

One mean directrix between two routes goes where no demonstration went (LASA's
``Multi_Models_1..4``: measured leave-one-out, 6-12x the best peer's DTW). The demonstrations are
clustered into routes first, and each route gets its own canal.

Clustering. Each demonstration is resampled to ``ROUTE_SAMPLES`` points by arc length; the
distance between two demonstrations is the mean distance between their points,

    d_ij = (1 / M) sum_m |x_i(m) - x_j(m)|                                        (R1)

Routes are the clusters of average linkage cut at ``ROUTE_SEPARATION`` times the demos' median
path length L: two groups are separate routes when their demos are on average more than
0.25 L apart. Measured on the sets of BENCHMARKS.md: every LASA shape, UR5e, the generated logs
and the RAIL pressing, pushing and writing groups merge below 0.15 L; the LASA multi-route shapes
split at 0.45-0.78 L, the RAIL reaching groups (two goals half a metre apart) at 0.34-0.48 L.
A demonstration that goes a way of its own alone is a route of its own: its canal is the
demonstration with the envelope of the route nearest to it (average distance), scaled to its
length (:func:`canal_core.fit.fit_lone`, L1). A canal of the lone demonstration joined to its
nearest route would go between the two ways, where neither went (LASA ``Multi_Models_1``
held out leave-one-out: a route of two demonstrations leaves one alone in every fold that
holds the other out). A route whose demonstrations are all the same path (one file uploaded
twice) shows its way once too: it is fitted as the first of them, with a borrowed envelope.
Only when no route has two different demonstrations to lend its envelope does a route that
shows its way once (one demonstration, or copies of one) join the route nearest to it.
``routes=1`` forces one route (one canal).

Route numbers follow the order in which the demonstrations first appear. A correction kept over
a refit goes to the route its samples lie along (R3 of :func:`way_of`), so it follows its way
when deleting demonstrations renumbers the routes, or a refit has fewer.

Choosing a route. A start is given to the route whose entry holds it: inside that route's
canal, located in its first third. When exactly one route's entry holds it, that route ("entry").
Otherwise the route whose entry passes nearest the start,

    g_k = min_{i < N_k / 3} |x_0 - c_k(i)|                                        (R2)

(c_k the route's directrix): among all routes when no entry holds the start ("nearest"), among
those that hold it when several do ("shared": routes that share their start and part later;
the start cannot tell them apart, and the canal of all the demonstrations would go between
them, where no demonstration went). Measured leave-one-out on LASA's multi-route shapes and
RAIL reaching (``bench/quality.py``), the plain distance of (R2) picks better than the same
distance over the route's radius (which draws starts to the widest route) or the canal of all.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import InvalidInputError, ModelFormatError
from .options import DEFAULT_ROUTE_SEPARATION
from .validation import BoolArray, FloatArray, IntArray, check_int, check_point

#: Points per demonstration in the route distance (R1).
ROUTE_SAMPLES = 50
#: Demonstrations closer than this by (R1) (a share of the median path length) are the same
#: path: a route of nothing else shows its way once.
IDENTICAL = 1e-9
#: Routes are split where their demonstrations are on average this share of the median path
#: length apart (average linkage of R1); the fit option's default.
ROUTE_SEPARATION = DEFAULT_ROUTE_SEPARATION
#: The share of a route's sections that makes its entry.
ENTRY_SHARE = 1.0 / 3.0
FORMAT = "canal-routes"
FORMAT_VERSION = 1
#: Point pairs compared at once in (R1).
_ROUTE_BLOCK = 2_000_000


def _resampled(positions: FloatArray, m: int) -> FloatArray:
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(steps)])
    if s[-1] <= 0.0:
        return np.repeat(positions[:1], m, axis=0)
    keep = np.concatenate([[True], steps > 0.0])
    grid = np.linspace(0.0, s[-1], m)
    return np.column_stack([np.interp(grid, s[keep], positions[keep, d]) for d in range(positions.shape[1])])


def route_distances(demos: list[FloatArray]) -> FloatArray:
    """(R1) between every pair of demonstrations, over their median path length, shape (n, n)."""
    paths = np.stack([_resampled(np.asarray(d, dtype=np.float64), ROUTE_SAMPLES) for d in demos])
    lengths = [float(np.linalg.norm(np.diff(d, axis=0), axis=1).sum()) for d in demos]
    scale = max(float(np.median(lengths)), 1e-300)
    n = paths.shape[0]
    dist = np.empty((n, n), dtype=np.float64)
    # A block of rows at a time: the (n, n, M, D) difference of all pairs at once would need
    # gigabytes for a thousand demonstrations.
    rows = max(1, _ROUTE_BLOCK // max(n * ROUTE_SAMPLES, 1))
    for i in range(0, n, rows):
        diff = paths[i : i + rows, None, :, :] - paths[None, :, :, :]
        dist[i : i + rows] = np.linalg.norm(diff, axis=3).mean(axis=2)
    return np.asarray(dist / scale, dtype=np.float64)


def route_work(n_demos: int) -> float:
    """Point pairs (R1) compares for ``n_demos`` demonstrations (what clustering costs)."""
    return float(n_demos) ** 2 * ROUTE_SAMPLES


def route_labels(demos: list[FloatArray], routes: int | None = None,
                 separation: float = ROUTE_SEPARATION) -> IntArray:
    """Route 0, 1, ... of each demonstration (in order of first appearance), shape (n,):
    average linkage of (R1) cut at ``separation``, or into ``routes`` clusters when given
    (:func:`route_split`)."""
    return route_split(demos, routes, separation).labels


@dataclass(frozen=True, eq=False)
class RouteSplit:
    """The demonstrations' routes, and which of them went a way of their own alone."""

    #: Route 0, 1, ... of each demonstration, shape (n,).
    labels: IntArray
    #: Demonstrations of a route that showed its way once (one demonstration, or copies of
    #: one) while no route had two different ones to lend its envelope: the route joined the
    #: route nearest to it (indices, in order).
    joined: tuple[int, ...]
    #: The first demonstration of each route that shows its way once, which borrows the
    #: envelope of the route in ``donors`` (indices, in order).
    lone: tuple[int, ...] = ()
    #: The route each of ``lone`` borrows its envelope from.
    donors: tuple[int, ...] = ()
    #: Demonstrations that are copies of one path and made a route of their own in the
    #: clustering (groups of indices, in order), whether the route then borrowed or joined.
    repeats: tuple[tuple[int, ...], ...] = ()


def route_split(demos: list[FloatArray], routes: int | None = None,
                separation: float = ROUTE_SEPARATION) -> RouteSplit:
    """:func:`route_labels`, and the routes that show their way once: those that joined
    another route, those that borrow an envelope, and the copies among them."""
    from scipy.cluster.hierarchy import fcluster, linkage
    from scipy.spatial.distance import squareform

    n = len(demos)
    if routes is not None:
        check_int(routes, 1, "routes")
        if routes > max(n // 2, 1):
            raise InvalidInputError(f"expected routes <= {max(n // 2, 1)} (each route needs 2 "
                                    f"demonstrations; {n} are fitted), got {routes}", field="routes")
    # Three demonstrations already make a route of two and a way shown once.
    if n < 3 or routes == 1:
        return RouteSplit(np.zeros(n, dtype=np.int64), ())
    dist = route_distances(demos)
    tree = linkage(squareform(dist, checks=False), "average")
    if routes is None:
        raw = fcluster(tree, separation, criterion="distance")
    else:
        raw = fcluster(tree, routes, criterion="maxclust")
    labels = _in_order(np.unique(raw, return_inverse=True)[1].astype(np.int64))
    once = shown_once(labels, dist)
    repeats = tuple(tuple(int(i) for i in members) for members in
                    (np.flatnonzero(labels == k) for k in np.flatnonzero(once)) if members.size > 1)
    # Copies of one path show its way no wider than one demonstration does: a route of them
    # has no envelope to lend either. A route that shows its way once joins the route nearest
    # to it (average distance) only while no route has two different demonstrations.
    joined: list[int] = []
    while once.size > 1 and once.all():
        members = np.flatnonzero(labels == 0)
        joined.extend(int(j) for j in members)
        labels[members] = _nearest_route(int(members[0]), range(1, once.size), labels, dist)
        labels = _in_order(np.unique(labels, return_inverse=True)[1].astype(np.int64))
        once = shown_once(labels, dist)
    # Lone demonstrations that joined each other make a route of their own: not joined.
    alone = np.zeros(n, dtype=bool)
    alone[joined] = True
    kept = tuple(j for j in sorted(joined) if np.any(~alone & (labels == labels[j])))
    lone_demos, donors = _lone_routes(labels, dist)
    return RouteSplit(labels, kept, lone_demos, donors, repeats)


def _in_order(labels: IntArray) -> IntArray:
    """Routes renumbered so that route 0 is the first demonstration's, route 1 the next new
    one's, ..., shape (n,)."""
    _, first = np.unique(labels, return_index=True)
    rank = np.argsort(np.argsort(first))
    return np.asarray(rank[labels], dtype=np.int64)


def _nearest_route(j: int, among: Any, labels: IntArray, dist: FloatArray) -> int:
    """Of the routes ``among``, the one whose demonstrations are nearest demonstration ``j``
    on average (R1)."""
    return int(min(among, key=lambda k: float(dist[j, labels == k].mean())))


def same_path(dist: FloatArray) -> bool:
    """Whether demonstrations with these (R1) distances (M, M) are all one path: every pair
    within :data:`IDENTICAL` (one demonstration is one path)."""
    return bool(np.all(dist <= IDENTICAL))


def shown_once(labels: IntArray, dist: FloatArray) -> BoolArray:
    """Per route (R,): True when it shows its way once: one demonstration, or several that
    are the same path (:func:`same_path`)."""
    once = np.ones(int(labels.max(initial=-1)) + 1, dtype=bool)
    for k in range(once.size):
        members = np.flatnonzero(labels == k)
        once[k] = same_path(dist[np.ix_(members, members)])
    return once


def _lone_routes(labels: IntArray, dist: FloatArray) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """The first demonstration of each route that shows its way once, and the route of two
    or more different demonstrations nearest each."""
    once = shown_once(labels, dist)
    shared = np.flatnonzero(~once)
    lone = tuple(int(np.flatnonzero(labels == k)[0]) for k in np.flatnonzero(once))
    if not lone or shared.size == 0:
        return (), ()
    return lone, tuple(_nearest_route(j, shared, labels, dist) for j in lone)


def _donor_routes(labels: IntArray, lone: tuple[int, ...], donors: tuple[int, ...]) -> dict[int, int]:
    """Route of each lone demonstration -> the route that lends it its envelope."""
    return {int(labels[j]): k for j, k in zip(lone, donors, strict=True)}


def route_donors(demos: list[FloatArray], labels: IntArray) -> dict[int, int]:
    """For each route that shows its way once (:func:`shown_once`), the route of two or more
    different demonstrations that lends it its envelope: the nearest by (R1), as
    :func:`route_split` chooses. Raises :class:`InvalidInputError` when no route has two
    different demonstrations (:func:`route_split` joins such routes instead)."""
    dist = route_distances(demos)
    once = shown_once(labels, dist)
    if not np.any(once):
        return {}
    if np.all(once):
        raise InvalidInputError(f"expected a route of at least 2 different demonstrations to lend its "
                                f"envelope to the routes of one, got routes each of one demonstration "
                                f"or copies of one (route sizes {np.bincount(labels).tolist()})",
                                field="labels")
    return _donor_routes(labels, *_lone_routes(labels, dist))


@dataclass(frozen=True, eq=False)
class RouteChoice:
    """Which canal a start follows: ``route`` (None: the canal of all demonstrations, which
    :meth:`Routes.choose` answers for a model of one route only) and why."""

    route: int | None
    #: "entry" (one route's entry holds the start), "nearest" (none holds it: the nearest
    #: entry), "shared" (several hold it: the nearest of those), "single" (one route only).
    reason: str


@dataclass(frozen=True, eq=False)
class Routes:
    """One canal per route, and the canal of all the demonstrations.

    Attributes
    ----------
    canals : tuple of Canal
        One per route, in route order.
    pooled : Canal
        Fitted on every demonstration (what a single-route fit gives).
    labels : array of int, shape (n,)
        The route of each demonstration, in the order given to :func:`fit_routes`.
    """

    canals: tuple[Any, ...]
    pooled: Any
    labels: IntArray

    @property
    def n_routes(self) -> int:
        return len(self.canals)

    @property
    def every_canal(self) -> tuple[Any, ...]:
        """Each canal the model holds once: the canal of all, then each route's when there
        are several."""
        return (self.pooled, *self.canals) if self.n_routes > 1 else (self.pooled,)

    def choose(self, start: Any) -> RouteChoice:
        """The route a start follows (see the module docstring)."""
        if self.n_routes == 1:
            return RouteChoice(None, "single")
        point = check_point(start, self.pooled.dim, "start")
        held, gaps = [], []
        for k, canal in enumerate(self.canals):
            entry = max(int(np.ceil(ENTRY_SHARE * canal.n_sections)), 1)
            loc = canal.locate(point[None, :])
            if bool(canal.contains(point[None, :])[0]) and int(loc.index[0]) < entry:
                held.append(k)
            gaps.append(float(np.linalg.norm(canal.directrix[:entry] - point, axis=1).min()))  # (R2)
        if len(held) == 1:
            return RouteChoice(held[0], "entry")
        if len(held) > 1:
            return RouteChoice(min(held, key=gaps.__getitem__), "shared")
        return RouteChoice(int(np.argmin(gaps)), "nearest")

    def canal_for(self, choice: RouteChoice) -> Any:
        return self.pooled if choice.route is None else self.canals[choice.route]

    def reproduce_detailed(self, start: Any, **kwargs: Any) -> tuple[RouteChoice, Any]:
        """(the route chosen, its :class:`~canal_core.reproduction.Reproduction`)."""
        choice = self.choose(start)
        return choice, self.canal_for(choice).reproduce_detailed(start, **kwargs)

    def contains(self, points: Any) -> Any:
        """Whether each point (M, D) is inside some route's canal (or the canal of all)."""
        inside = np.asarray(self.pooled.contains(points))
        for canal in self.canals:
            inside = inside | np.asarray(canal.contains(points))
        return inside

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able dict (format ``canal-routes`` version 1) of every canal's model."""
        return {"format": FORMAT, "version": FORMAT_VERSION, "labels": self.labels.tolist(),
                "routes": [c.to_dict() for c in self.canals], "pooled": self.pooled.to_dict()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Routes:
        """Rebuild what :meth:`to_dict` wrote; raises :class:`ModelFormatError`."""
        from .model import Canal

        if data.get("format") != FORMAT or data.get("version") != FORMAT_VERSION:
            raise ModelFormatError(f"expected format {FORMAT!r} version {FORMAT_VERSION}, got "
                                   f"{data.get('format')!r} version {data.get('version')!r}", field="format")
        try:
            canals = tuple(Canal.from_dict(c) for c in data["routes"])
            labels = np.asarray(data["labels"], dtype=np.int64)
            pooled = Canal.from_dict(data["pooled"])
        except (KeyError, TypeError, ValueError) as exc:
            raise ModelFormatError(f"malformed routes model: {exc!r}") from exc
        if not canals or labels.ndim != 1 or (labels.size and (labels.min() < 0 or labels.max() >= len(canals))):
            raise ModelFormatError(f"expected route labels in 0..{len(canals) - 1}, got {labels.tolist()}",
                                   field="labels")
        return cls(canals, pooled, labels)


def way_of(routes: Routes, points: Any, keep: int | None = None) -> int:
    """The route whose directrix passes nearest ``points`` (M, D): the least mean distance
    from each point to the directrix's nearest sample,

        h_k = (1 / M) sum_m min_i |p_m - c_k(i)|                                   (R3)

    ``keep`` (a route number, or None) stays unless another route is less than half as far:
    a correction kept over a refit follows the way it was made on when the routes are
    renumbered or fewer, and keeps its number where routes share their way."""
    pts = np.asarray(points, dtype=np.float64)
    gaps = []
    for canal in routes.canals:
        c = np.asarray(canal.directrix, dtype=np.float64)
        step = max(1, _ROUTE_BLOCK // max(c.shape[0], 1))
        nearest = np.concatenate([
            np.linalg.norm(pts[i:i + step, None, :] - c[None, :, :], axis=2).min(axis=1)
            for i in range(0, pts.shape[0], step)])
        gaps.append(float(nearest.mean()))
    best = int(np.argmin(gaps))
    if keep is not None and 0 <= keep < len(gaps) and not gaps[best] < 0.5 * gaps[keep]:
        return keep
    return best


def single_route(canal: Any) -> Routes:
    """A one-route :class:`Routes` of ``canal`` (what a single-canal model is as routes)."""
    return Routes((canal,), canal, np.zeros(max(int(canal.n_demos), 0), dtype=np.int64))


def served_model(routes: Routes) -> Any:
    """What a model is outside this module: its canal when it has one route (stored in the
    ``canal-model`` format and served as a single canal), else the :class:`Routes`."""
    return routes.pooled if routes.n_routes == 1 else routes


def routes_from_dict(data: dict[str, Any]) -> Routes:
    """Either stored model format as :class:`Routes`: ``canal-routes``, or a single
    ``canal-model`` as one route (:func:`single_route`)."""
    from .model import Canal

    if isinstance(data, dict) and data.get("format") == FORMAT:
        return Routes.from_dict(data)
    return single_route(Canal.from_dict(data))


def fit_routes(demos: Any, timestamps: Any = None, routes: int | None = None,
               separation: float = ROUTE_SEPARATION, labels: Any = None,
               **options: Any) -> Routes:
    """Cluster demonstrations into routes and fit one canal per route (and one of all).

    Parameters
    ----------
    demos, timestamps
        As :func:`canal_core.fit`.
    routes : int, optional
        Force this many routes (1: one canal, as :func:`canal_core.fit`).
    separation : float
        The cut of the clustering in shares of the median path length (R1).
    labels : array of int, shape (n,), optional
        The route of each demonstration, from :func:`route_labels` already (``routes`` and
        ``separation`` are then not used).
    **options
        Passed to every :func:`canal_core.fit`; ``orientations`` (one per demonstration) is
        split between the routes as the demonstrations are.
    """
    from .fit import fit, fit_lone
    from .preprocess import STILL_TOLERANCE

    if not isinstance(demos, (list, tuple)) or len(demos) < 2:
        raise InvalidInputError("expected a list of at least 2 demonstrations", field="demos")
    arrays = [np.asarray(d, dtype=np.float64) for d in demos]
    pooled = fit(demos, timestamps, **options)
    donors: dict[int, int] | None = None
    if labels is None:
        split = route_split(arrays, routes, separation)
        labels, donors = split.labels, _donor_routes(split.labels, split.lone, split.donors)
    else:
        labels = np.asarray(labels, dtype=np.int64)
        if labels.shape != (len(arrays),) or labels.min() < 0:
            raise InvalidInputError(f"expected one route label >= 0 per demonstration ({len(arrays)}), "
                                    f"got {labels.tolist()}", field="labels")
    if labels.max(initial=0) == 0:
        return Routes((pooled,), pooled, labels)
    if donors is None:
        donors = route_donors(arrays, labels)
    stamps = [None] * len(arrays) if timestamps is None else list(timestamps)
    quats = options.pop("orientations", None)
    canals: list[Any] = [None] * (int(labels.max()) + 1)
    # Routes of two demonstrations or more first: they lend their envelopes to the lone ones.
    for k in sorted(range(len(canals)), key=lambda k: k in donors):
        members = np.flatnonzero(labels == k)
        if k in donors:
            j = int(members[0])
            canals[k] = fit_lone(demos[j], canals[donors[k]], stamps[j],
                                 None if quats is None else quats[j],
                                 still_tolerance=options.get("still_tolerance", STILL_TOLERANCE))
            continue
        member_stamps = [stamps[j] for j in members]
        canals[k] = fit([demos[j] for j in members],
                        None if all(s is None for s in member_stamps) else member_stamps,
                        orientations=None if quats is None else [quats[j] for j in members],
                        **options)
    return Routes(tuple(canals), pooled, labels)
