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


def test_a_lone_demonstration_joins_the_nearest_route_and_is_named() -> None:
    from canal_core.routes import route_split

    s = np.linspace(0.0, 1.0, 120)
    over = np.column_stack([s, 0.1 * (1 - s), 0.5 * np.sin(np.pi * s)])  # over the top, once
    demos = two_route_demos()
    split = route_split([*demos, over])
    assert split.labels.max() == 1 and split.joined == (8,)
    assert route_split(demos).joined == ()
    # two lone ways of one demonstration each that are near each other make a route of two
    twice = route_split([*demos, over, over + 0.01])
    assert twice.labels.max() == 2 and twice.joined == ()
