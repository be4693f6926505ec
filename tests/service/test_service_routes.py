"""Routes over real HTTP: demonstrations that go two ways are fitted as two canals, a start
follows the route whose entry holds it, and a one-route fit answers as a single canal."""

from __future__ import annotations

from collections.abc import Iterator

import httpx
import numpy as np
import pytest
from canal_service.app import create_app
from canal_service.core.config import Settings
from canal_service.fitting import FitJob, FitRunner
from canal_testing import ROUTE_STARTS, LiveServer, path_distance, two_route_demo

import canal_core


def add_two_route_demos(http: httpx.Client, skill: str = "reach") -> list[int]:
    assert http.post("/skills", json={"name": skill, "dim": 3}).status_code == 201
    ids = []
    for j in range(8):
        r = http.post(f"/skills/{skill}/demonstrations",
                      json={"positions": two_route_demo(j).tolist()})
        assert r.status_code == 201, r.text
        ids.append(r.json()["id"])
    return ids


@pytest.fixture
def http(live_server: LiveServer) -> Iterator[httpx.Client]:
    with httpx.Client(base_url=live_server.url, timeout=60) as client:
        yield client


def test_two_ways_fit_two_routes_and_each_start_follows_its_own(http: httpx.Client) -> None:
    ids = add_two_route_demos(http)
    r = http.post("/skills/reach/fit", json={"n_samples": 60})
    assert r.status_code == 201, r.text
    fitted = r.json()
    assert fitted["routes"] == 2 and fitted["demo_ids"] == ids
    assert fitted["demo_routes"] == [0] * 4 + [1] * 4
    assert fitted["options"]["routes"] == 2

    model = http.get("/skills/reach/models/latest", params={"serialized": True}).json()
    assert model["routes"] == 2 and [c["route"] for c in model["route_canals"]] == [0, 1]
    assert [c["n_demos"] for c in model["route_canals"]] == [4, 4]
    assert model["serialized"]["format"] == "canal-routes"
    routes = canal_core.routes.routes_from_dict(model["serialized"])
    assert routes.n_routes == 2

    demos = [two_route_demo(j) for j in range(8)]
    for k, start in enumerate(ROUTE_STARTS):
        r = http.post("/skills/reach/reproductions", json={"start": list(start)})
        assert r.status_code == 200, r.text
        out = r.json()
        assert (out["route"], out["route_reason"]) == (k, "entry")
        own = min(path_distance(out["positions"], d) for d in demos[4 * k: 4 * k + 4])
        other = min(path_distance(out["positions"], d) for d in demos[4 * (1 - k): 4 * (1 - k) + 4])
        assert own < 0.05 < other, (k, own, other)
        # The middle of the path is on its route's side of the obstacle.
        middle = np.asarray(out["positions"])[len(out["positions"]) // 2]
        assert np.sign(middle[1]) == (1.0 if k == 0 else -1.0)

    batch = http.post("/skills/reach/reproductions",
                      json={"starts": [list(s) for s in ROUTE_STARTS]}).json()["reproductions"]
    assert [b["route"] for b in batch] == [0, 1]


def test_a_forced_route_is_followed_and_one_out_of_range_is_refused(http: httpx.Client) -> None:
    add_two_route_demos(http)
    assert http.post("/skills/reach/fit", json={"n_samples": 60}).status_code == 201
    r = http.post("/skills/reach/reproductions", json={"start": list(ROUTE_STARTS[0]), "route": 1})
    assert r.status_code == 200, r.text
    out = r.json()
    assert (out["route"], out["route_reason"]) == (1, "forced")
    assert np.asarray(out["positions"])[len(out["positions"]) // 2][1] < 0.0
    r = http.post("/skills/reach/reproductions", json={"start": list(ROUTE_STARTS[0]), "route": 2})
    assert r.status_code == 422
    error = r.json()["error"]
    assert error["field"] == "route" and "0..1" in error["message"]


def test_routes_1_gives_the_single_canal_answer(http: httpx.Client) -> None:
    add_two_route_demos(http)
    r = http.post("/skills/reach/fit", json={"n_samples": 60, "routes": 1})
    assert r.status_code == 201, r.text
    fitted = r.json()
    assert fitted["routes"] == 1 and fitted["demo_routes"] is None
    assert "routes" not in fitted["options"] and "demo_routes" not in fitted["options"]
    model = http.get("/skills/reach/models/1", params={"serialized": True}).json()
    assert model["serialized"]["format"] == "canal-model" and model["route_canals"] is None
    canal = canal_core.Canal.from_dict(model["serialized"])
    out = http.post("/skills/reach/reproductions", json={"start": list(ROUTE_STARTS[0])}).json()
    assert (out["route"], out["route_reason"]) == (None, "single")
    np.testing.assert_allclose(out["positions"], canal.reproduce(np.array(ROUTE_STARTS[0])),
                               atol=1e-9)


def test_route_options_out_of_bounds_are_refused_naming_the_field(http: httpx.Client) -> None:
    add_two_route_demos(http)
    for body, field in (({"routes": 5}, "routes"), ({"routes": 0}, "routes"),
                        ({"route_separation": 0}, "route_separation"),
                        ({"route_separation": 1e-320}, "route_separation"),
                        ({"route_separation": 1e-6}, "route_separation"),
                        ({"routes": 2, "demo_ids": [1, 2, 3]}, "routes")):
        r = http.post("/skills/reach/fit", json={"n_samples": 40, **body})
        assert r.status_code == 422, (body, r.text)
        assert field in (r.json()["error"]["field"] or ""), (body, r.json())
    assert http.get("/skills/reach").json()["n_models"] == 0


def two_routes_and_a_widening(http: httpx.Client) -> tuple[canal_core.Routes, np.ndarray]:
    """The two-route skill fitted, and samples beside its route 1: an include of that route."""
    add_two_route_demos(http)
    assert http.post("/skills/reach/fit", json={"n_samples": 60}).status_code == 201
    routes = _latest_routes(http)
    return routes, _widening(routes.canals[1])


def test_a_correction_names_its_route_and_the_model_keeps_its_routes(http: httpx.Client) -> None:
    routes, samples = two_routes_and_a_widening(http)
    r = http.post("/skills/reach/corrections",
                  json={"kind": "include", "samples": samples.tolist(), "route": 1})
    assert r.status_code == 201, r.text
    made = r.json()
    assert made["routes"] == 2 and made["correction"]["route"] == 1
    after = canal_core.routes.routes_from_dict(
        http.get("/skills/reach/models/latest", params={"serialized": True}).json()["serialized"])
    assert len(after.canals[1].corrections) == 1 and len(after.canals[0].corrections) == 0
    assert float(after.canals[1].radii[30]) > float(routes.canals[1].radii[30])
    np.testing.assert_allclose(after.canals[0].directrix, routes.canals[0].directrix)
    listed = http.get("/skills/reach/corrections").json()["items"]
    assert [c["route"] for c in listed] == [1]
    r = http.post("/skills/reach/corrections",
                  json={"kind": "include", "samples": samples.tolist(), "route": 3})
    assert r.status_code == 422 and r.json()["error"]["field"] == "route"
    # A refit keeps the routes and re-applies the correction to its route.
    r = http.post("/skills/reach/fit", json={"n_samples": 60})
    assert r.status_code == 201, r.text
    assert r.json()["routes"] == 2 and r.json()["corrections"] == [made["correction"]["id"]]
    refit = canal_core.routes.routes_from_dict(
        http.get("/skills/reach/models/latest", params={"serialized": True}).json()["serialized"])
    assert len(refit.canals[1].corrections) == 1 and len(refit.canals[0].corrections) == 0
    # Undone: a new version of two routes without it.
    r = http.delete(f"/skills/reach/corrections/{made['correction']['id']}")
    assert r.status_code == 200, r.text
    assert r.json()["routes"] == 2 and r.json()["corrections"] == []
    undone = canal_core.routes.routes_from_dict(
        http.get("/skills/reach/models/latest", params={"serialized": True}).json()["serialized"])
    assert undone.n_routes == 2 and not any(c.corrections for c in undone.canals)


def test_a_correction_for_every_route_stores_the_span_of_the_route_it_refines(
        http: httpx.Client) -> None:
    # With "route": null the correction refines the routes its samples lie along, but the
    # stored first_section..last_section were the canal of all's (which no reproduction
    # follows), not the route's: the listing pointed at sections the correction did not change.
    routes, samples = two_routes_and_a_widening(http)
    spans = {}
    for route in (1, None):
        r = http.post("/skills/reach/corrections",
                      json={"kind": "include", "samples": samples.tolist(), "route": route,
                            "model": 1})
        assert r.status_code == 201, r.text
        made = r.json()["correction"]
        spans[route] = (made["first_section"], made["last_section"])
    assert spans[None] == spans[1], spans


def test_a_correction_only_the_canal_of_all_takes_is_refused_naming_samples(
        http: httpx.Client) -> None:
    # A path between the routes, with no route named: only the canal of all the
    # demonstrations holds it, and no reproduction or live stream follows that canal. It was
    # stored as a new latest version that changed nothing a robot follows.
    routes, _samples = two_routes_and_a_widening(http)
    pooled = routes.pooled
    idx = np.arange(25, 36)
    between = pooled.directrix[idx] + 0.2 * pooled.radii[idx, None] * pooled.normals[idx]
    assert not any(c.contains(between).any() for c in routes.canals)
    r = http.post("/skills/reach/corrections",
                  json={"kind": "include", "samples": between.tolist(), "label": "between"})
    assert r.status_code == 422, r.text
    error = r.json()["error"]
    assert error["field"] == "samples"
    assert "route 0" in error["message"] and "route 1" in error["message"]
    assert "`route`" in error["message"]
    assert http.get("/skills/reach").json()["n_models"] == 1
    assert http.get("/skills/reach/corrections").json()["total"] == 0


def test_a_stored_model_loads_after_a_restart(tmp_path: object, settings: Settings) -> None:
    with LiveServer(create_app(settings)) as server, \
            httpx.Client(base_url=server.url, timeout=60) as http:
        add_two_route_demos(http)
        assert http.post("/skills/reach/fit", json={"n_samples": 60, "routes": 1}).status_code == 201
        assert http.post("/skills/reach/fit", json={"n_samples": 60}).status_code == 201
    # A new process's cache is empty: both formats are decoded from their rows.
    with LiveServer(create_app(settings)) as server, \
            httpx.Client(base_url=server.url, timeout=60) as http:
        one = http.post("/skills/reach/reproductions",
                        json={"start": list(ROUTE_STARTS[1]), "model": 1}).json()
        two = http.post("/skills/reach/reproductions",
                        json={"start": list(ROUTE_STARTS[1]), "model": 2}).json()
        assert (one["route"], one["route_reason"]) == (None, "single")
        assert (two["route"], two["route_reason"]) == (1, "entry")
        assert http.get("/skills/reach/models/1/mesh", params={"format": "json"}).status_code == 200
        assert http.get("/skills/reach/models/2/mesh", params={"format": "json"}).status_code == 200


def test_the_fit_estimate_counts_every_route_fit() -> None:
    runner = FitRunner(1e9)
    demos = [two_route_demo(j, n=400) for j in range(8)]
    one = FitJob(demos, None, None, None, {"n_samples": 400, "alignment": "dtw"})
    two = FitJob(demos, None, None, None, {"n_samples": 400, "alignment": "dtw"},
                 [0] * 4 + [1] * 4)
    assert runner.check_cost(two) == pytest.approx(2 * runner.check_cost(one))
    small = FitRunner(1.5 * runner.check_cost(one))
    small.check_cost(one)
    with pytest.raises(Exception, match="2 routes"):
        small.check_cost(two)


def _latest_routes(http: httpx.Client) -> canal_core.Routes:
    return canal_core.routes.routes_from_dict(
        http.get("/skills/reach/models/latest", params={"serialized": True}).json()["serialized"])


def _widening(canal: canal_core.Canal) -> np.ndarray:
    idx = np.arange(20, 41)
    return canal.directrix[idx] + 1.5 * canal.radii[idx, None] * canal.normals[idx]


def test_a_kept_correction_follows_its_way_when_a_refit_renumbers_the_routes(
        http: httpx.Client) -> None:
    # Route numbers follow the first demonstration of each way: the -y way is route 1 while
    # demonstration 0 (+y) comes first, route 0 once it is deleted.
    assert http.post("/skills", json={"name": "reach", "dim": 3}).status_code == 201
    ids = {}
    for j in (0, 4, 5, 6, 1, 2, 3, 7):
        r = http.post("/skills/reach/demonstrations", json={"positions": two_route_demo(j).tolist()})
        ids[j] = r.json()["id"]
    assert http.post("/skills/reach/fit", json={"n_samples": 60}).status_code == 201
    minus_y = _latest_routes(http).canals[1]
    assert minus_y.directrix[30, 1] < 0
    made = http.post("/skills/reach/corrections", json={
        "kind": "include", "samples": _widening(minus_y).tolist(), "route": 1}).json()
    assert http.delete(f"/skills/reach/demonstrations/{ids[0]}").status_code in (200, 204)
    r = http.post("/skills/reach/fit", json={"n_samples": 60})
    assert r.status_code == 201, r.text
    assert r.json()["corrections"] == [made["correction"]["id"]]
    refit = _latest_routes(http)
    assert refit.canals[0].directrix[30, 1] < 0  # the -y way is route 0 now
    assert [len(c.corrections) for c in refit.canals] == [1, 0]
    assert any("route 1 is now route 0" in note for note in r.json()["notes"]), r.json()["notes"]
    # the stored correction now names the route it follows, and the next refit keeps it there
    assert [c["route"] for c in http.get("/skills/reach/corrections").json()["items"]] == [0]
    again = http.post("/skills/reach/fit", json={"n_samples": 60}).json()
    assert not any("follows its way" in note for note in again["notes"])
    assert [len(c.corrections) for c in _latest_routes(http).canals] == [1, 0]


def test_a_correction_of_a_route_a_refit_no_longer_has_goes_to_the_nearest(
        http: httpx.Client) -> None:
    add_two_route_demos(http)
    assert http.post("/skills/reach/fit", json={"n_samples": 60, "routes": 3}).status_code == 201
    three = _latest_routes(http)
    last = three.canals[2]
    made = http.post("/skills/reach/corrections", json={
        "kind": "include", "samples": _widening(last).tolist(), "route": 2}).json()
    r = http.post("/skills/reach/fit", json={"n_samples": 60, "routes": 2})
    assert r.status_code == 201, r.text
    assert r.json()["corrections"] == [made["correction"]["id"]]
    two = _latest_routes(http)
    way = int(np.argmin([path_distance(last.directrix, c.directrix) for c in two.canals]))
    assert [len(c.corrections) for c in two.canals] == [int(k == way) for k in range(2)]


def test_a_demonstration_that_goes_its_own_way_alone_is_a_route_named_in_the_fit_notes(
        http: httpx.Client) -> None:
    add_two_route_demos(http)
    s = np.linspace(0.0, 1.0, 120)
    over = np.column_stack([s, 0.1 * (1 - s), 0.5 * np.sin(np.pi * s)])  # over the top, once
    lone = http.post("/skills/reach/demonstrations", json={"positions": over.tolist()}).json()["id"]
    r = http.post("/skills/reach/fit", json={"n_samples": 60})
    assert r.status_code == 201, r.text
    assert r.json()["routes"] == 3 and r.json()["demo_routes"][-1] == 2
    (note,) = [n for n in r.json()["notes"] if "way of its own" in n]
    assert f"demonstration {lone} " in note and "it is route 2, with the width of route" in note
    version = r.json()["version"]
    model = http.get(f"/skills/reach/models/{version}").json()
    assert [c["n_demos"] for c in model["route_canals"]] == [4, 4, 1]
    plain = http.post("/skills/reach/fit", json={"n_samples": 60, "demo_ids": list(range(1, 9))})
    assert plain.status_code == 201 and plain.json()["notes"] == []


def test_a_way_uploaded_twice_fits_as_a_way_shown_once_and_the_notes_say_so(http: httpx.Client) -> None:
    add_two_route_demos(http)
    s = np.linspace(0.0, 1.0, 120)
    over = np.column_stack([s, 0.1 * (1 - s), 0.5 * np.sin(np.pi * s)])
    twice = [http.post("/skills/reach/demonstrations", json={"positions": over.tolist()}).json()["id"]
             for _ in range(2)]
    r = http.post("/skills/reach/fit", json={"n_samples": 60})
    assert r.status_code == 201, r.text
    assert r.json()["routes"] == 3 and r.json()["demo_routes"][-2:] == [2, 2]
    (note,) = [n for n in r.json()["notes"] if "identical" in n]
    assert f"demonstrations {twice[0]} and {twice[1]} are identical" in note and "route 2" in note


@pytest.mark.parametrize(("factor", "hint"), [(1000.0, "millimetres among metres"),
                                             (0.001, "metres among millimetres"),
                                             (30.0, None)])
def test_a_demonstration_in_other_units_is_named_in_the_fit_notes(
        http: httpx.Client, factor: float, hint: str | None) -> None:
    # A UR log in millimetres among demonstrations in metres was fitted without a word: it
    # became a route of its own, or (with routes 1) a canal a thousand times too wide.
    assert http.post("/skills", json={"name": "units", "dim": 3}).status_code == 201
    s = np.linspace(0.0, 1.0, 120)
    ids = []
    for j in range(4):
        demo = np.column_stack([0.4 * s, 0.1 * np.sin(np.pi * s) + 0.01 * j, 0.2 + 0.05 * s])
        if j == 3:
            demo = demo * factor
        ids.append(http.post("/skills/units/demonstrations", json={"positions": demo.tolist()}).json()["id"])
    for routes in (None, 1):
        r = http.post("/skills/units/fit", json={"n_samples": 60, "routes": routes})
        assert r.status_code == 201, r.text
        notes = [n for n in r.json()["notes"] if "units" in n]
        assert len(notes) == 1, r.json()["notes"]
        assert notes[0].startswith(f"demonstration {ids[3]} is "), notes
        assert (hint in notes[0]) if hint else ("among" not in notes[0]), notes
    same = http.post("/skills/units/fit", json={"n_samples": 60, "demo_ids": ids[:3]})
    assert same.status_code == 201 and same.json()["notes"] == [], same.json()


@pytest.mark.parametrize("copies", [2, 3])
def test_a_way_uploaded_again_with_one_other_way_fits_one_route_and_the_notes_say_so(
        http: httpx.Client, copies: int) -> None:
    assert http.post("/skills", json={"name": "dup", "dim": 3}).status_code == 201
    ids = [http.post("/skills/dup/demonstrations", json={"positions": two_route_demo(j).tolist()}
                     ).json()["id"] for j in [0] * copies + [4]]
    named = ", ".join(map(str, ids[:copies - 1])) + f" and {ids[copies - 1]} are identical"
    for body in ({"n_samples": 30}, {"n_samples": 30, "route_separation": 0.05}):
        r = http.post("/skills/dup/fit", json=body)
        assert r.status_code == 201, r.text
        assert r.json()["routes"] == 1 and r.json()["demo_routes"] is None
        (note,) = r.json()["notes"]
        assert f"demonstrations {named}" in note and "joined route 0" in note, note
    # The other way uploaded first: it joins the copies' route, and both are named.
    assert http.post("/skills", json={"name": "dup2", "dim": 3}).status_code == 201
    ids = [http.post("/skills/dup2/demonstrations", json={"positions": two_route_demo(j).tolist()}
                     ).json()["id"] for j in [4] + [0] * copies]
    r = http.post("/skills/dup2/fit", json={"n_samples": 30})
    assert r.status_code == 201 and r.json()["routes"] == 1, r.text
    joined, copied = r.json()["notes"]
    assert f"demonstration {ids[0]} goes a way of its own" in joined and "joined route 0" in joined
    named = ", ".join(map(str, ids[1:-1])) + f" and {ids[-1]} are identical"
    assert f"demonstrations {named}" in copied, copied
