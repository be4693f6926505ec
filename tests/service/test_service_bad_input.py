"""Every bad input: a 4xx, a JSON error naming the field, and nothing stored."""

from __future__ import annotations

import io
import json
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from service_helpers import demo_positions

GOOD = demo_positions(0, n=6).tolist()


def stored(client: TestClient, skill: str = "pour") -> tuple[int, int]:
    """(demonstrations, models) stored for ``skill``."""
    s = client.get(f"/skills/{skill}").json()
    return s["n_demonstrations"], s["n_models"]


def assert_error(r: Any, status: int, field: str, error_type: str | None = None) -> dict[str, Any]:
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith("application/json")
    error = r.json()["error"]
    assert error["field"] is not None and field in error["field"], error
    assert error["message"]
    if error_type:
        assert error["type"] == error_type
    return error


def raw_json(text: str) -> dict[str, Any]:
    return {"content": text.encode(), "headers": {"content-type": "application/json"}}


# (what was tried, request kwargs, status, field named)
JSON_CASES: list[tuple[str, dict[str, Any], int, str]] = [
    ("NaN in a position (JSON NaN literal)",
     raw_json('{"positions": [[0,0,0],[1,0,0],[2,0,0],[3,0,NaN]]}'), 422, "positions[3]"),
    ("Infinity in a position",
     raw_json('{"positions": [[0,0,0],[1,0,0],[2,Infinity,0],[3,0,0]]}'), 422, "positions[2]"),
    ("a number too large for float64 (overflows to inf)",
     raw_json('{"positions": [[0,0,0],[1,0,0],[2,1e999,0],[3,0,0]]}'), 422, "positions[2]"),
    ("ragged rows", {"json": {"positions": [[0, 0, 0], [1, 0, 0], [2, 0], [3, 0, 0]]}}, 422,
     "positions[2]"),
    ("2 columns for a 3-D skill", {"json": {"positions": [[0, 0], [1, 0], [2, 0], [3, 0]]}}, 422,
     "positions[0]"),
    ("4 columns for a 3-D skill",
     {"json": {"positions": [[0, 0, 0, 0], [1, 0, 0, 0], [2, 0, 0, 0], [3, 0, 0, 0]]}}, 422,
     "positions[0]"),
    ("3 points (fewer than 4)", {"json": {"positions": GOOD[:3]}}, 422, "positions"),
    ("no points", {"json": {"positions": []}}, 422, "positions"),
    # equal stamps and one late sample are a raw log's, accepted (test_service_upload_prepared);
    # time going back for good is not
    ("timestamps going back for good (a clock reset)",
     {"json": {"positions": GOOD, "timestamps": [0, 1, 2, 0.1, 0.2, 0.3]}}, 422, "timestamps"),
    ("timestamps length mismatch", {"json": {"positions": GOOD, "timestamps": [0, 1, 2]}}, 422,
     "timestamps"),
    ("NaN timestamp", raw_json(json.dumps({"positions": GOOD}).replace(
        "}", ', "timestamps": [0, 1, NaN, 3, 4, 5]}')), 422, "timestamps[2]"),
    ("non-unit quaternion",
     {"json": {"positions": GOOD, "orientations": [[0, 0, 0, 1]] * 3 + [[0, 0, 0, 2]] +
               [[0, 0, 0, 1]] * 2}}, 422, "orientations[3]"),
    ("quaternions with 3 components", {"json": {"positions": GOOD, "orientations": [[0, 0, 1]] * 6}},
     422, "orientations[0]"),
    ("orientations length mismatch", {"json": {"positions": GOOD, "orientations": [[0, 0, 0, 1]]}},
     422, "orientations"),
    ("empty JSON body", raw_json(""), 422, "body"),
    ("malformed JSON", raw_json('{"positions": [[0,0,0],'), 422, "body"),
    ("JSON array instead of object", raw_json("[[0,0,0]]"), 422, "body"),
    ("strings as coordinates", {"json": {"positions": [["a", 0, 0]] * 4}}, 422, "positions[0][0]"),
    # true and "1" must not become 1.0
    ("true as a coordinate", {"json": {"positions": [[0, 0, True], *GOOD[1:]]}}, 422,
     "positions[0][2]"),
    ('"1" (a string) as a coordinate', {"json": {"positions": [*GOOD[:2], ["1", 0, 0], *GOOD[3:]]}},
     422, "positions[2][0]"),
    ("false as a timestamp", {"json": {"positions": GOOD, "timestamps": [False, 1, 2, 3, 4, 5]}},
     422, "timestamps[0]"),
    ('"1" in a quaternion', {"json": {"positions": GOOD, "orientations": [[0, 0, 0, "1"]] * 6}},
     422, "orientations[0][3]"),
    ("unknown key (typo)", {"json": {"position": GOOD}}, 422, "position"),
    ("missing positions", {"json": {"label": "x"}}, 422, "positions"),
    ("label with a NUL byte", {"json": {"positions": GOOD, "label": "a\u0000b"}}, 422, "label"),
    ("wrong content type", {"content": b"positions", "headers": {"content-type": "image/png"}},
     415, "Content-Type"),
    ("no content type", {"content": b"x,y,z\n"}, 415, "Content-Type"),
]


@pytest.mark.parametrize(("tried", "kwargs", "status", "field"), JSON_CASES,
                         ids=[c[0] for c in JSON_CASES])
def test_bad_demonstration_is_refused_and_not_stored(
    client: TestClient, skill: str, tried: str, kwargs: dict[str, Any], status: int, field: str
) -> None:
    before = stored(client)
    r = client.post(f"/skills/{skill}/demonstrations", **kwargs)
    assert_error(r, status, field)
    assert stored(client) == before, f"{tried}: something was stored"
    assert client.get(f"/skills/{skill}/demonstrations").json()["items"] == []


def _npy(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array, allow_pickle=True)
    return buf.getvalue()


def _npy_header(shape: str) -> bytes:
    """A version 1.0 .npy header (and no data) promising an array of ``shape``."""
    header = "{'descr': '<f8', 'fortran_order': False, 'shape': " + shape + ", }"
    header += " " * (63 - (len(header) + 10) % 64) + "\n"
    return b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header.encode()


GARBAGE = bytes(range(256)) * 8
FILE_CASES: list[tuple[str, str, bytes, int, str]] = [
    ("garbage bytes as MCAP", "mcap", GARBAGE, 400, "file"),
    ("MCAP magic then garbage", "mcap", b"\x89MCAP0\r\n" + GARBAGE, 400, "file"),
    ("garbage bytes as NPY", "npy", GARBAGE, 400, "file"),
    ("NPY magic then garbage", "npy", b"\x93NUMPY\x01\x00" + GARBAGE, 400, "file"),
    ("NPY header promising more data than sent", "npy", _npy(np.zeros((50, 3)))[:-8], 400, "file"),
    ("pickled object array in an NPY (must never be unpickled)", "npy",
     _npy(np.array([{"a": 1}] * 4, dtype=object)), 400, "file"),
    ("NPY of strings", "npy", _npy(np.array([["a", "b", "c"]] * 4)), 400, "file"),
    ("NPY with the wrong number of columns", "npy", _npy(np.zeros((10, 5))), 422, "file"),
    ("NPY header with a shape past 64 bits", "npy", _npy_header("(99999999999999999999, 3)"), 400,
     "file"),
    ("NPY header with a negative shape", "npy", _npy_header("(-4, 3)"), 400, "file"),
    ("NPY with NaN", "npy", _npy(np.full((10, 3), np.nan)), 422, "positions[0]"),
    ("garbage bytes as CSV", "csv", GARBAGE, 400, "file"),
    ("empty file", "csv", b"", 400, "file"),
    ("CSV with text in a number column", "csv", b"x,y,z\n1,2,3\n1,two,3\n1,2,3\n1,2,3\n", 422,
     "line 3"),
    ("CSV with a ragged line", "csv", b"x,y,z\n1,2,3\n1,2\n1,2,3\n1,2,3\n", 422, "line 3"),
    ("CSV with a duplicate x column (a spreadsheet export)", "csv",
     b"x,y,z,x\n1,2,3,9\n2,2,3,9\n3,2,3,9\n4,2,3,9\n", 422, "header"),
    ("CSV with two time columns", "csv",
     b"t,time,x,y,z\n0,5,1,2,3\n1,4,2,2,3\n2,3,3,2,3\n3,2,4,2,3\n", 422, "header"),
    ("CSV with true as a number", "csv", b"x,y,z\n1,2,3\n1,true,3\n1,2,3\n1,2,3\n", 422,
     "line 3"),
    ("CSV without x/y/z header columns", "csv", b"a,b,c\n1,2,3\n1,2,3\n1,2,3\n1,2,3\n", 422,
     "header"),
    ("CSV whose t goes back for good", "csv",
     b"t,x,y,z\n0,1,2,3\n1,1,2,4\n2,1,2,5\n3,1,2,6\n0.1,1,2,7\n0.2,1,2,8\n", 422,
     "timestamps"),
]


@pytest.mark.parametrize(("tried", "fmt", "data", "status", "field"), FILE_CASES,
                         ids=[c[0] for c in FILE_CASES])
def test_bad_upload_is_refused_and_not_stored(
    client: TestClient, skill: str, tried: str, fmt: str, data: bytes, status: int, field: str
) -> None:
    before = stored(client)
    r = client.post(f"/skills/{skill}/demonstrations", files={"file": (f"demo.{fmt}", data)})
    assert_error(r, status, field)
    # the same bytes as a raw body with ?format=
    r = client.post(f"/skills/{skill}/demonstrations?format={fmt}", content=data,
                    headers={"content-type": "application/octet-stream"})
    assert 400 <= r.status_code < 500, (tried, r.text)
    assert stored(client) == before, f"{tried}: something was stored"


def test_multipart_without_file_field(client: TestClient, skill: str) -> None:
    r = client.post(f"/skills/{skill}/demonstrations", data={"label": "x"},
                    files={"other": ("a.csv", b"x,y,z\n")})
    assert_error(r, 422, "file")
    assert stored(client) == (0, 0)


def test_unknown_format_cannot_be_guessed(client: TestClient, skill: str) -> None:
    r = client.post(f"/skills/{skill}/demonstrations", content=b"1,2,3\n",
                    headers={"content-type": "application/octet-stream"})
    assert_error(r, 422, "format")
    assert stored(client) == (0, 0)


def test_unknown_skill(client: TestClient) -> None:
    r = client.post("/skills/nope/demonstrations", json={"positions": GOOD})
    assert_error(r, 404, "name", "not_found")
    for path in ("/skills/nope", "/skills/nope/demonstrations", "/skills/nope/models",
                 "/skills/nope/models/latest", "/skills/nope/models/latest/mesh"):
        assert_error(client.get(path), 404, "name")
    assert_error(client.post("/skills/nope/fit", json={}), 404, "name")
    assert_error(client.post("/skills/nope/reproductions", json={"start": [0, 0, 0]}), 404, "name")
    assert_error(client.delete("/skills/nope"), 404, "name")
    assert client.get("/skills").json()["total"] == 0


@pytest.mark.parametrize(("tried", "body", "field"), [
    ("empty name", {"name": "", "dim": 3}, "name"),
    ("name with a slash", {"name": "a/b", "dim": 3}, "name"),
    ("dimension 4", {"name": "a", "dim": 4}, "dim"),
    ("dimension as text", {"name": "a", "dim": "three"}, "dim"),
    ("dimension 3.0 (a fraction's type)", {"name": "a", "dim": 3.0}, "dim"),
    ("dimension true", {"name": "a", "dim": True}, "dim"),
    ("missing name", {"dim": 3}, "name"),
])
def test_bad_skill_is_refused(client: TestClient, tried: str, body: dict[str, Any],
                              field: str) -> None:
    assert_error(client.post("/skills", json=body), 422, field)
    assert client.get("/skills").json()["total"] == 0, tried


def test_duplicate_skill_is_a_conflict(client: TestClient, skill: str) -> None:
    r = client.post("/skills", json={"name": skill, "dim": 2})
    assert_error(r, 409, "name", "conflict")
    assert client.get(f"/skills/{skill}").json()["dim"] == 3


def test_a_name_that_differs_only_in_letter_case_is_a_conflict(client: TestClient, skill: str) -> None:
    # "Pour" beside "pour" was a second skill, and on a case-insensitive file system (macOS,
    # Windows) both recorded into one folder.
    for other in (skill.upper(), skill.capitalize(), skill.swapcase()):
        r = client.post("/skills", json={"name": other, "dim": 3})
        error = assert_error(r, 409, "name", "conflict")
        assert repr(skill) in error["message"] and "letter case" in error["message"], error
        assert client.get(f"/skills/{other}").status_code == 404
    assert client.post("/skills", json={"name": skill + "-2", "dim": 3}).status_code == 201


def test_fit_with_fewer_than_two_demos(client: TestClient, skill: str) -> None:
    assert_error(client.post(f"/skills/{skill}/fit", json={}), 409, "demonstrations")
    client.post(f"/skills/{skill}/demonstrations", json={"positions": GOOD})
    assert_error(client.post(f"/skills/{skill}/fit", json={}), 409, "demonstrations")
    assert stored(client) == (1, 0)


@pytest.mark.parametrize(("tried", "body", "field"), [
    ("unknown cross-section", {"cross_section": "square"}, "cross_section"),
    ("n_samples 1", {"n_samples": 1}, "n_samples"),
    ("n_samples huge", {"n_samples": 10**9}, "n_samples"),
    ("unknown demo id", {"demo_ids": [1, 999]}, "demo_ids"),
    # A selection a fit cannot use is the request's fault (422 on demo_ids), not the skill's
    # state (409); a repeated id would be fitted once, not twice as it reads.
    ("no demo ids", {"demo_ids": []}, "demo_ids"),
    ("one demo id", {"demo_ids": [1]}, "demo_ids"),
    ("a demo id twice", {"demo_ids": [1, 2, 1]}, "demo_ids"),
    ("unknown option", {"smoothing": 3}, "smoothing"),
    # A JSON type other than the field's is refused, not coerced: true is not 1 route,
    # "no" is not false, "100" is not a number of sections.
    ("true as a number of routes", {"routes": True}, "routes"),
    ('"100" (a string) as n_samples', {"n_samples": "100"}, "n_samples"),
    ('"no" (a string) as keep_corrections', {"keep_corrections": "no"}, "keep_corrections"),
    ("0 as orientation", {"orientation": 0}, "orientation"),
    ("true as route_separation", {"route_separation": True}, "route_separation"),
    ("true as a demo id", {"demo_ids": [1, True]}, "demo_ids[1]"),
])
def test_bad_fit_request(client: TestClient, fitted: str, tried: str, body: dict[str, Any],
                         field: str) -> None:
    before = stored(client)
    assert_error(client.post(f"/skills/{fitted}/fit", json=body), 422, field)
    assert stored(client) == before, tried


def test_fit_on_identical_demos_is_degenerate(client: TestClient, skill: str) -> None:
    for _ in range(3):
        client.post(f"/skills/{skill}/demonstrations", json={"positions": demo_positions(0).tolist()})
    error = assert_error(client.post(f"/skills/{skill}/fit", json={}), 422, "")
    assert error["type"] in ("degenerate_canal", "invalid_input")
    assert stored(client) == (3, 0)


def test_unfittable_demonstration_is_refused_at_upload(client: TestClient, skill: str) -> None:
    # Uploads run canal_core's preparation, so a demo the fit would refuse is
    # refused when it arrives (it used to be stored and then block every fit of the skill).
    ok = client.post(f"/skills/{skill}/demonstrations", json={"positions": GOOD})
    assert ok.status_code == 201, ok.text
    still = [[0.0, 0.0, 0.0]] * 3 + [[1.0, 0.0, 0.0]] * 3  # only 2 distinct samples
    error = assert_error(client.post(f"/skills/{skill}/demonstrations", json={"positions": still}),
                         422, "positions")
    assert "distinct moving samples" in error["message"]
    assert stored(client) == (1, 0)


def test_reproduce_before_any_fit(client: TestClient, skill: str) -> None:
    r = client.post(f"/skills/{skill}/reproductions", json={"start": [0, 0, 0]})
    assert_error(r, 409, "model", "conflict")
    assert_error(client.get(f"/skills/{skill}/models/latest"), 409, "model")


@pytest.mark.parametrize(("tried", "body", "status", "field"), [
    ("start with 2 coordinates on a 3-D skill", {"start": [0, 0]}, 422, "start"),
    ("start with 4 coordinates", {"start": [0, 0, 0, 0]}, 422, "start"),
    ("NaN start", "NaN", 422, "start"),
    ("start and starts together", {"start": [0, 0, 0], "starts": [[0, 0, 0]]}, 422, "body"),
    ("neither start nor starts", {}, 422, "body"),
    ("one bad start in a batch", {"starts": [[0, 0, 0], [0, 0]]}, 422, "starts[1]"),
    ("unknown model version", {"start": [0, 0, 0], "model": 7}, 404, "model"),
    ("model as a word", {"start": [0, 0, 0], "model": "newest"}, 422, "model"),
    ("unknown outside policy", {"start": [0, 0, 0], "outside": "clamp"}, 422, "outside"),
    ("unknown persistence", {"start": [0, 0, 0], "persistence": "forever"}, 422, "persistence"),
    ("goal with 2 coordinates on a 3-D skill", {"start": [0, 0, 0], "goal": [1, 0]}, 422, "goal"),
    ("goal with 4 coordinates", {"start": [0, 0, 0], "goal": [1, 0, 0, 0]}, 422, "goal"),
    ("zero duration", {"start": [0, 0, 0], "duration": 0}, 422, "duration"),
    ("negative duration", {"start": [0, 0, 0], "duration": -2.0}, 422, "duration"),
    ("start orientation of 3 numbers", {"start": [0, 0, 0], "start_orientation": [0, 0, 1]}, 422,
     "start_orientation"),
    # A JSON type other than the field's is refused, not coerced: a robot must not start from
    # [1, 0, 0] because a client sent true, nor follow version 1 or route 0 by a boolean.
    ("true as a start coordinate", {"start": [True, 0, 0]}, 422, "start[0]"),
    ('"0.5" (a string) as a start coordinate', {"start": [0, "0.5", 0]}, 422, "start[1]"),
    ("false in a batch start", {"starts": [[0, 0, 0], [0, 0, False]]}, 422, "starts[1][2]"),
    ("true as a goal coordinate", {"start": [0, 0, 0], "goal": [True, 0, 0]}, 422, "goal[0]"),
    ("true as a model version", {"start": [0, 0, 0], "model": True}, 422, "model"),
    ('"1" (a string) as a model version', {"start": [0, 0, 0], "model": "1"}, 422, "model"),
    ("true as a duration", {"start": [0, 0, 0], "duration": True}, 422, "duration"),
    ('"2" (a string) as a duration', {"start": [0, 0, 0], "duration": "2"}, 422, "duration"),
    ("false as a route", {"start": [0, 0, 0], "route": False}, 422, "route"),
    ("true as a start orientation component",
     {"start": [0, 0, 0], "start_orientation": [0, 0, 0, True]}, 422, "start_orientation[3]"),
    ("true as an obstacle's clearance",
     {"start": [0, 0, 0], "obstacles": [{"kind": "sphere", "center": [5, 5, 5], "radius": 0.1,
                                         "clearance": True}]}, 422, "obstacles[0].clearance"),
])
def test_bad_reproduction_request(client: TestClient, fitted: str, tried: str, body: Any,
                                  status: int, field: str) -> None:
    if body == "NaN":
        r = client.post(f"/skills/{fitted}/reproductions", **raw_json('{"start": [0, NaN, 0]}'))
    else:
        r = client.post(f"/skills/{fitted}/reproductions", json=body)
    assert_error(r, status, field)
    assert stored(client) == (4, 1), tried


@pytest.mark.parametrize("model", [0, -1, 2**31, 10**20, 1.5, "newest", True, "1", None, [1], {"v": 1}])
@pytest.mark.parametrize("route", ["reproductions", "corrections"])
def test_a_bad_model_version_is_named_model_with_what_is_expected(
    client: TestClient, fitted: str, model: Any, route: str
) -> None:
    # Named "model.literal['latest']" with "Input should be 'latest'" before, whatever was
    # sent: the reader was told a number is not allowed.
    body = {"start": [0, 0, 0]} if route == "reproductions" else {"kind": "include", "samples": [[0, 0, 0]] * 8}
    error = assert_error(client.post(f"/skills/{fitted}/{route}", json={**body, "model": model}), 422, "model")
    assert error["field"] == "model", error
    assert f"expected 'latest' or a model version from 1 to {2**31 - 1}, got" in error["message"], error
    assert stored(client) == (4, 1)


@pytest.mark.parametrize("n_samples", [2, 3])
def test_a_goal_where_a_short_canal_starts_is_refused(client: TestClient, skill: str,
                                                      n_samples: int) -> None:
    # A canal bent to end at its own start shrinks to a point when it has two sections: no
    # tangent, and the request was a 500.
    for j in range(4):
        client.post(f"/skills/{skill}/demonstrations", json={"positions": demo_positions(j).tolist()})
    assert client.post(f"/skills/{skill}/fit", json={"n_samples": n_samples}).status_code == 201
    model = client.get(f"/skills/{skill}/models/latest", params={"serialized": True}).json()
    start = model["serialized"]["directrix"][0]
    r = client.post(f"/skills/{skill}/reproductions", json={"start": start, "goal": start})
    if n_samples == 2:
        error = assert_error(r, 422, "goal")
        assert "start" in error["message"], error
    else:
        assert r.status_code == 200, r.text
    assert stored(client) == (4, 1)


def test_start_outside_the_canal(client: TestClient, fitted: str) -> None:
    far = [0.0, 5.0, 0.0]
    r = client.post(f"/skills/{fitted}/reproductions", json={"start": far})
    assert r.status_code == 200, r.text
    assert r.json()["inside"] is False and r.json()["projected"] is True
    r = client.post(f"/skills/{fitted}/reproductions", json={"start": far, "outside": "raise"})
    assert_error(r, 422, "start", "outside_canal")
    r = client.post(f"/skills/{fitted}/reproductions",
                    json={"starts": [[0.0, 0.0, 0.0], far], "outside": "raise"})
    assert_error(r, 422, "starts[1]", "outside_canal")


def test_bad_ids_and_versions_in_paths(client: TestClient, fitted: str) -> None:
    assert_error(client.get(f"/skills/{fitted}/demonstrations/0"), 422, "id")
    assert_error(client.get(f"/skills/{fitted}/demonstrations/99"), 404, "id")
    assert_error(client.delete(f"/skills/{fitted}/demonstrations/99"), 404, "id")
    # The path's {id} (docs/rest.md) is what a refusal and a 404 both name.
    assert_error(client.delete(f"/skills/{fitted}/demonstrations/0"), 422, "id")
    assert_error(client.delete(f"/skills/{fitted}/corrections/0"), 422, "id")
    assert_error(client.delete(f"/skills/{fitted}/corrections/99"), 404, "id")
    assert_error(client.get(f"/skills/{fitted}/models/99"), 404, "model")
    assert_error(client.get(f"/skills/{fitted}/models/first"), 422, "version")
    assert_error(client.get(f"/skills/{fitted}/models/1/mesh?format=stl"), 422, "format")
    assert_error(client.get(f"/skills/{fitted}/demonstrations?limit=0"), 422, "limit")
    assert stored(client) == (4, 1)


@pytest.mark.parametrize(("path", "body", "field", "got"), [
    ("/skills/pour/reproductions", {"start": [0, 0, 0], "route": "a"}, "route", 'got "a"'),
    ("/skills/pour/reproductions", {"start": [0, 0, 0], "route": -1}, "route", "got -1"),
    ("/skills/pour/reproductions", {"start": [0, 0, 0], "duration": True}, "duration", "got true"),
    ("/skills/pour/reproductions", {"start": [0, 0, "x"]}, "start[2]", 'got "x"'),
    ("/skills/pour/reproductions", {"start": [0, 0, 0], "outside": "skip"}, "outside", 'got "skip"'),
    ("/skills/pour/fit", {"n_samples": 1.5}, "n_samples", "got 1.5"),
    ("/skills/pour/fit", {"n_samples": [200]}, "n_samples", "got a list"),
    ("/skills", {"name": "a name", "dim": 3}, "name", 'got "a name"'),
    ("/skills", {"name": "arm", "dim": {"d": 3}}, "dim", "got an object"),
    # pydantic's "List should have at least 2 items after validation, not 1" was followed by
    # "got a list"
    ("/skills/pour/fit", {"demo_ids": [1]}, "demo_ids", "expected at least 2 items, got 1"),
])
def test_a_refused_value_is_shown_beside_what_was_expected(
    client: TestClient, fitted: str, path: str, body: dict[str, Any], field: str, got: str
) -> None:
    # The answer said what was expected ("Input should be a valid integer") but not what came,
    # so a client building its body by code could not see which value it had sent.
    error = assert_error(client.post(path, json=body), 422, field)
    assert error["field"] == field, error
    assert error["message"].endswith(got), error
    assert error["details"][0]["message"].endswith(got), error
    assert stored(client) == (4, 1)


def test_a_missing_field_says_so_without_a_value(client: TestClient, skill: str) -> None:
    error = assert_error(client.post("/skills/pour/reproductions", json={"outside": "raise"}), 422, "")
    assert "got" not in error["message"], error
    # pydantic's "Value error, " prefix is how the check was written, not what was wrong
    assert error["message"] == "body: give exactly one of 'start' or 'starts'", error
    error = assert_error(client.post("/skills", json={"dim": 3}), 422, "name")
    assert error["message"] == "name: Field required", error


@pytest.mark.parametrize("name", ["a name", "-lead", "x" * 65, "é"])
def test_a_bad_skill_name_says_which_names_are_allowed_in_words(client: TestClient, name: str) -> None:
    # The message quoted the regular expression ("String should match pattern
    # '^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$'"), in the body and in the path alike.
    words = "expected a skill name of 1 to 64 letters, digits, '.', '_' or '-', starting with a letter or digit"
    error = assert_error(client.post("/skills", json={"name": name, "dim": 3}), 422, "name")
    shown = json.dumps(name) if len(name) < 30 else json.dumps(name)[:37] + "..."
    assert error["message"] == f"name: {words}, got {shown}", error
    error = assert_error(client.get(f"/skills/{name}"), 422, "name")
    assert error["message"].startswith(f"name: {words}, got "), error


def test_a_number_in_a_query_is_shown_as_typed(client: TestClient, fitted: str) -> None:
    error = assert_error(client.get("/skills/pour/models/1/mesh?n_angles=2"), 422, "n_angles")
    assert error["message"].endswith(", got 2"), error
    error = assert_error(client.get("/skills/pour/models/1/mesh?format=stl"), 422, "format")
    assert error["message"].endswith(', got "stl"'), error
    error = assert_error(client.get("/skills?limit=0"), 422, "limit")
    assert error["message"].endswith(", got 0"), error
