"""Several routes: one canal per route, the route chosen by the start's entry."""

from __future__ import annotations

import json

import numpy as np
import pytest

import canal_core
from canal_core.routes import route_labels


def two_route_demos(n_each: int = 4, shared_start: bool = False) -> list[np.ndarray]:
    """Reaches along x that pass above (+y) or below (-y) an obstacle at the middle; starts
    apart by route (or all at one start)."""
    s = np.linspace(0.0, 1.0, 120)
    demos = []
    for side in (1.0, -1.0):
        for k in range(n_each):
            start_y = 0.0 if shared_start else side * 0.15
            y = start_y * (1 - s) + side * 0.4 * np.sin(np.pi * s) + 0.01 * (k - n_each / 2)
            demos.append(np.column_stack([s, y, 0.02 * np.cos(3 * k) * np.sin(np.pi * s)]))
    return demos


def test_demonstrations_that_go_different_ways_are_two_routes_and_one_route_can_be_forced() -> None:
    demos = two_route_demos()
    labels = route_labels(demos)
    assert labels.tolist() == [0] * 4 + [1] * 4
    assert route_labels(demos, routes=1).tolist() == [0] * 8
    # Demos of one route, spread by less than the separation, stay one route.
    assert route_labels(demos[:4]).tolist() == [0] * 4
    with pytest.raises(canal_core.InvalidInputError, match="routes"):
        route_labels(demos, routes=5)
    # Three demonstrations hold one route at most, whatever the clustering would say.
    with pytest.raises(canal_core.InvalidInputError, match="each route needs 2 demonstrations"):
        route_labels(demos[:3], routes=2)


def test_a_start_follows_the_route_whose_entry_holds_it_and_no_canal_between_them() -> None:
    demos = two_route_demos()
    routes = canal_core.fit_routes(demos, n_samples=60)
    assert routes.n_routes == 2
    for side, route in ((1.0, 0), (-1.0, 1)):
        start = np.array([0.0, side * 0.15 + 0.005, 0.0])
        choice, result = routes.reproduce_detailed(start)
        assert choice.route == route and choice.reason == "entry"
        mid = result.positions[result.positions.shape[0] // 2]
        assert side * mid[1] > 0.3  # over its own route, not between the two (y near 0)
        assert routes.canals[route].contains(result.positions[result.entry_index:]).all()
    # A start beside both entries takes the nearest one.
    assert routes.choose(np.array([0.0, -0.35, 0.0])).route == 1
    # One canal of all the demos would pass between the routes.
    pooled = canal_core.fit(demos, n_samples=60).reproduce_detailed(np.array([0.0, 0.155, 0.0]))
    assert abs(pooled.positions[pooled.positions.shape[0] // 2][1]) < 0.3


def test_routes_that_share_their_start_follow_one_demonstrated_route_and_say_so() -> None:
    routes = canal_core.fit_routes(two_route_demos(shared_start=True), n_samples=60)
    assert routes.n_routes == 2
    start = np.array([0.0, 0.0, 0.0])
    choice = routes.choose(start)
    assert choice.reason == "shared" and choice.route in (0, 1)
    # The route goes round the middle on its side, as its demonstrations did; the canal of
    # all would pass through the middle.
    path = routes.canal_for(choice).reproduce_detailed(start).positions
    assert abs(path[path.shape[0] // 2][1]) > 0.3
    pooled = routes.pooled.reproduce_detailed(start).positions
    assert abs(pooled[pooled.shape[0] // 2][1]) < 0.3


def test_a_routes_model_round_trips_and_a_bad_one_is_refused() -> None:
    routes = canal_core.fit_routes(two_route_demos(), n_samples=40)
    data = json.loads(json.dumps(routes.to_dict()))
    again = canal_core.Routes.from_dict(data)
    assert again.labels.tolist() == routes.labels.tolist()
    np.testing.assert_array_equal(again.canals[1].directrix, routes.canals[1].directrix)
    data["labels"] = [0, 7]
    with pytest.raises(canal_core.ModelFormatError, match="labels"):
        canal_core.Routes.from_dict(data)


def test_way_of_finds_the_route_points_lie_along_and_keeps_a_number_where_ways_are_shared() -> None:
    from canal_core.routes import way_of

    routes = canal_core.fit_routes(two_route_demos(shared_start=True), n_samples=60)
    assert routes.n_routes == 2
    first, second = (c.directrix for c in routes.canals)
    late = slice(40, 55)  # where the ways have parted
    assert way_of(routes, second[late]) == 1
    assert way_of(routes, second[late], keep=0) == 1  # renumbered: follows the way
    assert way_of(routes, first[late], keep=1) == 0
    assert way_of(routes, first[late], keep=5) == 0  # a route the model no longer has
    shared = 0.5 * (first[:3] + second[:3])  # the common start: either way is as near
    assert way_of(routes, shared, keep=1) == 1 and way_of(routes, shared, keep=0) == 0


def test_a_lone_demonstration_is_a_route_of_its_own_with_the_nearest_routes_envelope() -> None:
    from canal_core.routes import route_split

    s = np.linspace(0.0, 1.0, 120)
    over = np.column_stack([s, 0.1 * (1 - s), 0.5 * np.sin(np.pi * s)])  # over the top, once
    demos = two_route_demos()
    split = route_split([*demos, over])
    assert split.labels.tolist() == [0] * 4 + [1] * 4 + [2] and split.joined == ()
    assert split.lone == (8,) and split.donors in ((0,), (1,))
    assert route_split(demos).lone == () and route_split(demos).joined == ()
    # two lone ways of one demonstration each that are near each other make a route of two
    twice = route_split([*demos, over, over + 0.01])
    assert twice.labels.max() == 2 and twice.lone == ()

    routes = canal_core.fit_routes([*demos, over], n_samples=60)
    lone, donor = routes.canals[2], routes.canals[split.donors[0]]
    assert routes.n_routes == 3 and lone.n_sections == donor.n_sections == 60 and lone.n_demos == 1
    # Its directrix is the demonstration; its width the donor's, in proportion to its length (L1).
    gaps = np.linalg.norm(lone.directrix[:, None, :] - over[None, :, :], axis=2).min(axis=1)
    assert gaps.max() < 0.01 and np.allclose(lone.directrix[[0, -1]], over[[0, -1]])
    ratio = lone.arclength[-1] / donor.arclength[-1]
    assert np.all(lone.radii >= ratio * donor.radii * (1 - 1e-9))
    assert lone.contains(over).all()
    assert routes.contains(np.vstack([*demos, over])).all()
    # A start beside its start follows it over the top, not one of the ways round.
    choice, result = routes.reproduce_detailed(over[0] + np.array([0.0, 0.01, 0.0]))
    assert choice.route == 2
    assert result.positions[:, 2].max() > 0.4
    # With orientations, it keeps its own and borrows the donor's spread of them.
    turn = [np.tile([0.0, 0.0, np.sin(0.1 * k), np.cos(0.1 * k)], (len(d), 1)) for k, d in enumerate([*demos, over])]
    turned = canal_core.fit_routes([*demos, over], n_samples=60, orientations=turn)
    mean = turned.canals[2].orientation.means
    assert np.allclose(np.abs(mean @ turn[8][0]), 1.0)
    assert np.array_equal(turned.canals[2].orientation.spreads,
                          turned.canals[split.donors[0]].orientation.spreads)
    _, held = turned.reproduce_detailed(over[0] + np.array([0.0, 0.01, 0.0]), start_orientation=turn[7][0])
    assert held.orientation_eta is not None and np.isfinite(held.orientation_eta)
    # A model that round-trips keeps it.
    again = canal_core.routes.routes_from_dict(json.loads(json.dumps(routes.to_dict())))
    assert np.array_equal(again.canals[2].radii, lone.radii)


def test_lone_demonstrations_join_the_nearest_route_when_no_route_has_two() -> None:
    from canal_core.routes import route_split

    s = np.linspace(0.0, 1.0, 80)
    # four parallel ways a path length apart: every one alone
    ways = [np.column_stack([s, np.full_like(s, c) + 0.01 * s * s]) for c in (0.0, 1.0, 2.5, 4.5)]
    split = route_split(ways)
    # the first joins its nearest; the route of two lends its envelope to the others
    assert split.labels.tolist() == [0, 0, 1, 2] and split.joined == (0,)
    assert split.lone == (2, 3) and split.donors == (0, 0)
    # Labels that leave a route of one with no route of two to lend it a width are refused.
    with pytest.raises(canal_core.InvalidInputError, match="lend its envelope"):
        canal_core.fit_routes(ways[:2], labels=[0, 1], n_samples=40)


def test_a_way_uploaded_twice_is_a_way_shown_once_not_a_degenerate_fit() -> None:
    from canal_core.routes import route_split

    s = np.linspace(0.0, 1.0, 120)
    over = np.column_stack([s, 0.1 * (1 - s), 0.5 * np.sin(np.pi * s)])
    demos = two_route_demos()
    # The same file twice: a route of two identical demonstrations has no width of its own.
    split = route_split([*demos, over, over.copy()])
    assert split.labels.tolist() == [0] * 4 + [1] * 4 + [2, 2]
    assert split.lone == (8,) and split.donors in ((0,), (1,))
    routes = canal_core.fit_routes([*demos, over, over.copy()], n_samples=60)
    assert routes.canals[2].n_demos == 1 and routes.contains(over).all()
    choice, result = routes.reproduce_detailed(over[0] + np.array([0.0, 0.01, 0.0]))
    assert choice.route == 2 and np.allclose(result.positions[-1], over[-1], atol=1e-6)


def test_routes_of_identical_copies_join_when_no_route_has_two_different_demonstrations() -> None:
    from canal_core.routes import route_split

    demos = two_route_demos()
    above, below = demos[0], demos[4]
    # One file uploaded two or three times and one demonstration the other way: each way is
    # shown once, so no route has a width to lend; the copies join the other way's route.
    for ways in ([above, above.copy(), above.copy(), below], [above, above.copy(), below]):
        copies = tuple(range(len(ways) - 1))
        split = route_split(ways)
        assert split.labels.tolist() == [0] * len(ways) and split.lone == ()
        assert split.repeats == (copies,) and split.joined == copies
        routes = canal_core.fit_routes(ways, n_samples=30)
        assert routes.n_routes == 1 and routes.contains(np.vstack(ways)).all()
    # Both ways uploaded twice: one route of the two ways, each named as repeats.
    split = route_split([above, above.copy(), below, below.copy()])
    assert split.labels.tolist() == [0] * 4 and split.repeats == ((0, 1), (2, 3))
    assert split.joined == (0, 1)
    assert canal_core.fit_routes([above, above, below, below], n_samples=40).n_routes == 1
    # A route of two different demonstrations lends its width to a copied way, at three too.
    split = route_split([above, demos[1], below, below.copy()])
    assert split.labels.tolist() == [0, 0, 1, 1] and split.lone == (2,) and split.donors == (0,)
    assert split.repeats == ((2, 3),) and split.joined == ()
    three = route_split([above, demos[1], below])
    assert three.labels.tolist() == [0, 0, 1] and three.lone == (2,) and three.repeats == ()
    assert canal_core.fit_routes([above, demos[1], below], n_samples=30).n_routes == 2
    # Only copies of one way: there is no width to learn at all.
    with pytest.raises(canal_core.DegenerateCanalError, match="identical"):
        canal_core.fit_routes([above, above.copy(), above.copy()], n_samples=30)


def test_fit_lone_refuses_a_demonstration_of_another_dimension() -> None:
    from canal_core.fit import fit_lone

    donor = canal_core.fit(two_route_demos()[:4], n_samples=40)
    with pytest.raises(canal_core.InvalidInputError, match="dimension 3"):
        fit_lone(np.zeros((10, 2)) + np.linspace(0, 1, 10)[:, None], donor)
