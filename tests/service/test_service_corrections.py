"""Corrections over real HTTP: each one (and each undo) is a model version with its lineage."""

from __future__ import annotations

import json
import re
from collections.abc import Iterator

import httpx
import numpy as np
import pytest
from canal_service.app import create_app
from canal_service.core.config import Settings
from canal_service.fitting import FitJob, FitRunner, reapply_cost_seconds
from canal_service.storage import Database, ModelVersion
from canal_testing import LiveServer, foxglove_pose_mcap
from service_helpers import demo_positions
from sqlalchemy import select, update

import canal_core


@pytest.fixture
def http(live_server: LiveServer) -> Iterator[httpx.Client]:
    with httpx.Client(base_url=live_server.url, timeout=60) as client:
        assert client.post("/skills", json={"name": "pour", "dim": 3}).status_code == 201
        for j in range(5):
            r = client.post("/skills/pour/demonstrations", json={"positions": demo_positions(j).tolist()})
            assert r.status_code == 201, r.text
        assert client.post("/skills/pour/fit", json={"n_samples": 80}).status_code == 201
        yield client


def served_canal(http: httpx.Client, version: str = "latest") -> canal_core.Canal:
    r = http.get(f"/skills/pour/models/{version}", params={"serialized": True})
    assert r.status_code == 200, r.text
    return canal_core.Canal.from_dict(r.json()["serialized"])


def wider_path(canal: canal_core.Canal, first: int = 30, last: int = 50) -> list[list[float]]:
    idx = np.arange(first, last + 1)
    side = canal.radii[idx, None] * (1.2 + 0.5 * np.sin(np.linspace(0.0, np.pi, idx.size)))[:, None]
    return (canal.directrix[idx] + side * canal.normals[idx]).tolist()


def pushed_path(canal: canal_core.Canal, depth: float = 0.7) -> list[list[float]]:
    """The canal's own run from near its +normal wall, pushed towards -normal mid-way."""
    start = canal.directrix[10] + 0.8 * canal.radii[10] * canal.normals[10]
    run = canal.reproduce(start)
    k = np.arange(run.shape[0])
    sec = np.clip(10 + k, 0, canal.n_sections - 1)
    bump = np.exp(-0.5 * ((k - 30) / 6.0) ** 2)
    return (run - (depth * canal.radii[sec] * bump)[:, None] * canal.normals[sec]).tolist()


def test_a_correction_is_a_new_model_version_with_its_parent(http: httpx.Client) -> None:
    fitted = served_canal(http)
    r = http.post("/skills/pour/corrections",
                  json={"kind": "include", "samples": wider_path(fitted), "weight": 2.0, "label": "wider"})
    assert r.status_code == 201, r.text
    body = r.json()
    assert body["version"] == 2 and body["parent_version"] == 1
    correction = body["correction"]
    assert body["corrections"] == [correction["id"]]
    assert correction["kind"] == "include" and correction["label"] == "wider" and not correction["undone"]
    assert correction["base_version"] == 1 and correction["model_version"] == 2
    refined = served_canal(http)
    assert refined.parent == fitted.digest
    assert refined.contains(np.array(wider_path(fitted))).all()
    # Reproductions use the refined canal; the fit is still there.
    rep = http.post("/skills/pour/reproductions", json={"start": wider_path(fitted)[0]}).json()
    assert rep["model_version"] == 2
    models = http.get("/skills/pour/models").json()["items"]
    assert [(m["version"], m["parent_version"], m["corrections"]) for m in models] == [
        (2, 1, [correction["id"]]), (1, None, [])]
    listed = http.get("/skills/pour/corrections").json()
    assert listed["total"] == 1 and listed["items"][0]["id"] == correction["id"]
    metrics = http.get("/metrics").text
    assert 'canal_corrections_total{kind="include"} 1.0' in metrics


def test_undo_makes_a_version_without_the_correction(http: httpx.Client) -> None:
    fitted = served_canal(http)
    first = http.post("/skills/pour/corrections", json={"kind": "include", "samples": wider_path(fitted)}).json()
    second = http.post("/skills/pour/corrections", json={"kind": "exclude", "samples": pushed_path(fitted)})
    assert second.status_code == 201, second.text
    ids = [first["correction"]["id"], second.json()["correction"]["id"]]
    assert second.json()["corrections"] == ids and second.json()["parent_version"] == 2
    r = http.delete(f"/skills/pour/corrections/{ids[0]}")
    assert r.status_code == 200, r.text
    undone = r.json()
    assert undone["version"] == 4 and undone["parent_version"] == 3 and undone["corrections"] == [ids[1]]
    assert undone["correction"]["undone"]
    # The same canal as the exclude applied to the fit alone.
    only_exclude = fitted.corrected("exclude", pushed_path(fitted))
    assert np.array_equal(served_canal(http).directrix, only_exclude.directrix)
    again = http.delete(f"/skills/pour/corrections/{ids[0]}")
    assert again.status_code == 409 and again.json()["error"]["field"] == "id"
    assert http.delete("/skills/pour/corrections/999").status_code == 404
    listed = http.get("/skills/pour/corrections").json()["items"]
    assert [c["undone"] for c in listed] == [True, False]


def test_undone_says_whether_the_latest_version_holds_the_correction(http: httpx.Client) -> None:
    # A correction of a version made before an undo builds on that version's corrections,
    # the undone one among them: the latest holds it again, and the listing said it was
    # undone while every refit kept re-applying it.
    fitted = served_canal(http)
    a = http.post("/skills/pour/corrections",
                  json={"kind": "include", "samples": wider_path(fitted, 20, 35)}).json()
    b = http.post("/skills/pour/corrections",
                  json={"kind": "include", "samples": wider_path(fitted, 50, 65)}).json()
    ids = [a["correction"]["id"], b["correction"]["id"]]
    assert http.delete(f"/skills/pour/corrections/{ids[0]}").json()["corrections"] == [ids[1]]
    r = http.post("/skills/pour/corrections",
                  json={"kind": "include", "samples": wider_path(fitted, 38, 46),
                        "model": b["version"]})
    assert r.status_code == 201, r.text
    c = r.json()
    assert c["corrections"] == [*ids, c["correction"]["id"]]
    listed = {i["id"]: i["undone"] for i in http.get("/skills/pour/corrections").json()["items"]}
    assert listed == {ids[0]: False, ids[1]: False, c["correction"]["id"]: False}
    # a plain fit leaves every correction behind: none is in the latest version
    assert http.post("/skills/pour/fit", json={"n_samples": 80,
                                               "keep_corrections": False}).status_code == 201
    listed = {i["id"]: i["undone"] for i in http.get("/skills/pour/corrections").json()["items"]}
    assert set(listed.values()) == {True}


def test_a_refit_keeps_the_corrections_unless_asked_not_to(http: httpx.Client) -> None:
    fitted = served_canal(http)
    made = http.post("/skills/pour/corrections", json={"kind": "include", "samples": wider_path(fitted)}).json()
    r = http.post("/skills/pour/fit", json={"n_samples": 80})
    assert r.status_code == 201, r.text
    kept = r.json()
    assert kept["version"] == 4 and kept["parent_version"] == 3 and kept["corrections"] == [made["correction"]["id"]]
    assert served_canal(http, "3").corrections == ()
    assert served_canal(http).contains(np.array(wider_path(fitted))).all()
    plain = http.post("/skills/pour/fit", json={"n_samples": 80, "keep_corrections": False}).json()
    assert plain["version"] == 5 and plain["parent_version"] is None and plain["corrections"] == []
    # Left behind: the next refit has nothing to keep.
    assert http.post("/skills/pour/fit", json={"n_samples": 80}).json()["corrections"] == []


def test_a_correction_of_an_older_version_becomes_the_latest(http: httpx.Client) -> None:
    fitted = served_canal(http)
    http.post("/skills/pour/corrections", json={"kind": "include", "samples": wider_path(fitted)})
    r = http.post("/skills/pour/corrections",
                  json={"kind": "exclude", "samples": pushed_path(fitted), "model": 1})
    assert r.status_code == 201, r.text
    assert r.json()["version"] == 3 and r.json()["parent_version"] == 1 and len(r.json()["corrections"]) == 1


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"samples": [[0.0, 0.0]] * 10}, "samples"),  # a 2-D path for a 3-D skill
        ({"samples": [[0.0, 0.0, 0.0]] * 3}, "samples"),  # too short
        ({"samples": [[5.0 + 0.01 * i, 5.0, 5.0] for i in range(10)]}, "samples"),  # outside every section
        ({"kind": "sideways"}, "kind"),
        ({"weight": 0}, "weight"),
        ({"model": 7}, "model"),
        ({"model": True}, "model"),  # not version 1
        ({"weight": True}, "weight"),  # not 1.0
        ({"route": False}, "route"),  # not route 0
        # Time stamps a demonstration would be refused for: they never advance, or go back
        # for good (a clock reset) half-way.
        ({"timestamps": [1.0] * 21}, "timestamps"),
        ({"timestamps": [0.1 * i for i in range(11)] + [0.1 * i for i in range(10)]}, "timestamps"),
    ],
)
def test_bad_corrections_are_refused_naming_the_field_and_store_nothing(
    http: httpx.Client, change: dict[str, object], field: str
) -> None:
    fitted = served_canal(http)
    body = {"kind": "include", "samples": wider_path(fitted), **change}
    r = http.post("/skills/pour/corrections", json=body)
    assert r.status_code in (404, 422), r.text
    assert field in (r.json()["error"]["field"] or ""), r.json()
    assert http.get("/skills/pour/corrections").json()["total"] == 0
    assert http.get("/skills/pour/models").json()["total"] == 1


def test_a_correction_that_would_close_the_canal_is_refused(http: httpx.Client) -> None:
    fitted = served_canal(http)
    r = http.post("/skills/pour/corrections", json={"kind": "exclude", "samples": pushed_path(fitted, depth=2.5)})
    assert r.status_code == 422, r.text
    error = r.json()["error"]
    assert error["field"] == "kind" and "close the canal" in error["message"]
    assert http.get("/skills/pour/models").json()["total"] == 1



def test_a_glitch_sample_in_a_correction_is_left_out_and_the_answer_says_so(http: httpx.Client) -> None:
    # One sample of an include path thrown 2.5 radii out (an IK/TF glitch, a pose in the
    # wrong frame) used to double the canal's radius there, silently. It is dropped as a
    # demonstration's would be at fit; the samples are stored as they came.
    fitted = served_canal(http)
    idx = np.arange(20, 61)
    path = fitted.directrix[idx] + 0.9 * fitted.radii[idx, None] * fitted.normals[idx]
    spiky = path.copy()
    spiky[20] = fitted.directrix[40] + 2.5 * fitted.radii[40] * fitted.normals[40]
    clean = http.post("/skills/pour/corrections", json={"kind": "include", "samples": path.tolist()})
    assert clean.status_code == 201, clean.text
    assert not [n for n in clean.json()["notes"] if "glitch" in n]
    r = http.post("/skills/pour/corrections",
                  json={"kind": "include", "samples": spiky.tolist(), "model": 1})
    assert r.status_code == 201, r.text
    body = r.json()
    assert body["parent_version"] == 1 and body["correction"]["n_points"] == 41
    assert [n for n in body["notes"] if "glitch" in n] == [
        "1 of the 41 samples was left out as a glitch (far off the path and straight back, "
        "the rule demonstrations are cleaned by at fit): sample 20"]
    grown = served_canal(http).radii / fitted.radii
    assert grown.max() < 1.02 * (served_canal(http, "2").radii / fitted.radii).max()


def test_an_exclude_stays_local_and_its_answer_counts_what_its_blend_excludes(http: httpx.Client) -> None:
    # The robot on its directrix pushed half a radius off over the middle third: blended
    # gently, the exclude reached every section and left demonstrated starts outside.
    fitted = served_canal(http)
    idx = np.arange(25, 56)
    pushed = fitted.directrix[idx] + 0.5 * fitted.radii[idx, None] * fitted.normals[idx]
    r = http.post("/skills/pour/corrections", json={"kind": "exclude", "samples": pushed.tolist(),
                                                   "plan": fitted.directrix[idx].tolist()})
    assert r.status_code == 201, r.text
    refined = served_canal(http)
    applied = refined.corrections[0]
    blend = canal_core.corrections.longest_blend(fitted.n_sections)
    assert applied.first - blend <= applied.lo and applied.hi <= applied.last + blend
    changed = np.flatnonzero(np.any(refined.directrix != fitted.directrix, axis=1))
    assert applied.lo <= changed.min() and changed.max() <= applied.hi
    demos = [demo_positions(j) for j in range(5)]
    assert refined.contains(np.array([d[0] for d in demos])).all()
    lost = canal_core.corrections.blend_dropped_crossings(fitted, refined)
    notes = [n for n in r.json()["notes"] if "excluded by this correction" in n]
    assert len(notes) == 1, r.json()["notes"]
    said = re.fullmatch(rf"{int(lost.sum())} demonstrated crossings in sections (\d+)\.\.(\d+) and "
                        r"(\d+)\.\.(\d+), where the canal narrows into the exclude's span, are "
                        r"outside the corrected canal: excluded by this correction, as those "
                        r"on its excluded side are", notes[0])
    assert said is not None, notes[0]
    a, b, c, d = map(int, said.groups())
    assert applied.lo <= a <= b < applied.first and applied.last < c <= d <= applied.hi


def test_a_correction_s_plan_is_named_when_it_is_at_fault(http: httpx.Client) -> None:
    # The same pushed samples are a fine exclude with the directrix as plan; with a plan over
    # other sections or 5 m to the side the fault is the plan's, and an include takes none.
    fitted = served_canal(http)
    idx = np.arange(20, 40)
    pushed = (fitted.directrix[idx] + 0.5 * fitted.radii[idx, None] * fitted.normals[idx]).tolist()
    for plan in (fitted.directrix[50:70], fitted.directrix[idx] + [0.0, 5.0, 0.0]):
        r = http.post("/skills/pour/corrections", json={"kind": "exclude", "samples": pushed,
                                                       "plan": plan.tolist()})
        assert r.status_code == 422, r.text
        assert r.json()["error"]["field"] == "plan", r.json()
    r = http.post("/skills/pour/corrections", json={"kind": "include", "samples": wider_path(fitted),
                                                   "plan": fitted.directrix[30:51].tolist()})
    assert r.status_code == 422, r.text
    error = r.json()["error"]
    assert error["field"] == "plan" and "no plan on an include" in error["message"], error
    assert http.get("/skills/pour/corrections").json()["total"] == 0
    ok = http.post("/skills/pour/corrections", json={"kind": "exclude", "samples": pushed,
                                                    "plan": fitted.directrix[idx].tolist()})
    assert ok.status_code == 201, ok.text


def test_a_sample_row_a_value_short_is_named_in_words_not_numpy_s(http: httpx.Client) -> None:
    # Null rows and non-numbers are refused by the schema; a row of the wrong length reached
    # numpy and came back as "inhomogeneous shape after 1 dimensions".
    samples = wider_path(served_canal(http))
    samples[1] = samples[1][:2]
    r = http.post("/skills/pour/corrections", json={"kind": "include", "samples": samples})
    assert r.status_code == 422, r.text
    error = r.json()["error"]
    assert error["field"] == "samples[1]" and "got 2 values at row 1" in error["message"], error
    assert "inhomogeneous" not in error["message"]
    assert http.get("/skills/pour/corrections").json()["total"] == 0


def test_a_correction_sent_as_a_file_is_read_as_a_demonstration_upload(http: httpx.Client) -> None:
    # A person's corrected path comes from the logger they record demonstrations with: a UR
    # RTDE log, a ROS 2 bag. The same samples as JSON and as files make the same canal.
    fitted = served_canal(http)
    samples = np.asarray(wider_path(fitted))
    by_json = http.post("/skills/pour/corrections", json={"kind": "include", "samples": samples.tolist(),
                                                          "weight": 2.0, "label": "wider"})
    assert by_json.status_code == 201, by_json.text
    expected = served_canal(http)
    undone = http.delete(f"/skills/pour/corrections/{by_json.json()['correction']['id']}")
    assert undone.status_code == 200, undone.text
    t = np.arange(len(samples)) * 0.008
    rtde = "timestamp " + " ".join(f"actual_TCP_pose_{k}" for k in range(6)) + "\n" + "".join(
        " ".join(f"{v:.17g}" for v in (t[i], *samples[i], 0.0, 0.0, 0.0)) + "\n"
        for i in range(len(samples)))
    r = http.post("/skills/pour/corrections/file",
                  params={"kind": "include", "weight": 2, "label": "wider", "model": 1},
                  content=rtde.encode(), headers={"content-type": "text/csv"})
    assert r.status_code == 201, r.text
    made = r.json()
    assert made["correction"]["n_points"] == len(samples) and made["correction"]["label"] == "wider"
    assert made["correction"]["weight"] == 2.0 and made["parent_version"] == 1
    got = served_canal(http)
    np.testing.assert_allclose(got.directrix, expected.directrix)
    np.testing.assert_allclose(got.radii, expected.radii)
    # A ROS 2 / Foxglove bag as a multipart upload; its file name is the label.
    bag = foxglove_pose_mcap(samples)
    r = http.post("/skills/pour/corrections/file", params={"kind": "include"},
                  files={"file": ("pushed.mcap", bag, "application/octet-stream")})
    assert r.status_code == 201, r.text
    assert r.json()["correction"]["label"] == "pushed.mcap"
    assert r.json()["correction"]["n_points"] == len(samples)


@pytest.mark.parametrize(("params", "content", "status", "field", "said"), [
    ({}, b"x,y,z\n0,0,0\n", 422, "kind", "Field required"),
    ({"kind": "widen"}, b"x,y,z\n0,0,0\n", 422, "kind", "'include' or 'exclude'"),
    ({"kind": "include", "weight": 0}, b"x,y,z\n0,0,0\n", 422, "weight", "greater than 0"),
    ({"kind": "include", "model": "newest"}, b"x,y,z\n0,0,0\n", 422, "model", "'latest'"),
    ({"kind": "include", "model": 9}, b"x,y,z\n0,0,0\n1,0,0\n2,0,0\n3,0,0\n", 404, "model", "9"),
    ({"kind": "include"}, b"x,y\n0,0\n1,1\n2,2\n3,3\n", 422, "file:header", "x, y, z"),
    ({"kind": "include"}, b"x,y,z\n0,0,0\n1,oops,1\n", 422, "file:line 3", "'oops'"),
    ({"kind": "include", "format": "npy"}, b"x,y,z\n0,0,0\n", 400, "file", "npy"),
    ({"kind": "include"}, b"", 400, "file", "empty"),
    # a robot held still: the correction's own rule, not a demonstration's "cannot be fitted"
    ({"kind": "include"}, b"x,y,z\n" + b"0.4,0.1,0.01\n" * 5, 422, "samples", "move along the canal"),
    # a correction's rows are its samples, not a demonstration's positions
    ({"kind": "include"}, b"x,y,z\n0.1,0,0\nnan,0.01,0\n0.3,0,0\n0.4,0,0\n", 422, "samples[1]", "NaN"),
    ({"kind": "include"}, b"x,y,z\n0.1,0,0\n0.2,0,0\n", 422, "samples", "at least 4 points"),
])
def test_a_file_correction_refused_names_the_part_and_changes_nothing(
        http: httpx.Client, params: dict[str, object], content: bytes, status: int, field: str,
        said: str) -> None:
    before = http.get("/skills/pour/models").json()["total"]
    r = http.post("/skills/pour/corrections/file", params=params, content=content,
                  headers={"content-type": "text/csv"})
    assert r.status_code == status, r.text
    error = r.json()["error"]
    assert error["field"] == field and said in error["message"], error
    assert http.get("/skills/pour/models").json()["total"] == before
    assert http.get("/skills/pour/corrections").json()["total"] == 0


def test_a_corrections_time_unit_is_read_as_a_demonstrations_is(http: httpx.Client) -> None:
    # The file route did not read ?time_unit= (a query it did not take was dropped) while
    # its refusal of stamps in nanoseconds told the client to send it; a JSON correction's
    # stamps spanning 4 hours (milliseconds sent as seconds) were taken as they came.
    samples = np.asarray(wider_path(served_canal(http)))
    t_ns = np.arange(len(samples)) * 8_000_000
    csv = "t,x,y,z\n" + "".join(f"{t_ns[i]},{x:.17g},{y:.17g},{z:.17g}\n"
                                for i, (x, y, z) in enumerate(samples))
    before = http.get("/skills/pour/models").json()["total"]
    for params, field in (({"kind": "include"}, "timestamps"),
                          ({"kind": "include", "time_unit": "h"}, "time_unit")):
        r = http.post("/skills/pour/corrections/file", params=params, content=csv.encode(),
                      headers={"content-type": "text/csv"})
        assert r.status_code == 422 and r.json()["error"]["field"] == field, r.text
    bag = foxglove_pose_mcap(samples)
    r = http.post("/skills/pour/corrections/file", params={"kind": "include", "time_unit": "ms"},
                  files={"file": ("pushed.mcap", bag, "application/octet-stream")})
    assert r.status_code == 422 and r.json()["error"]["field"] == "time_unit", r.text
    r = http.post("/skills/pour/corrections", params={"time_unit": "ms"},
                  json={"kind": "include", "samples": samples.tolist()})  # no timestamps
    assert r.status_code == 422 and r.json()["error"]["field"] == "time_unit", r.text
    # no samples and no stamps, in microseconds: a 500 (the unit's shift read the first stamp)
    r = http.post("/skills/pour/corrections", params={"time_unit": "us"},
                  json={"kind": "include", "samples": [], "timestamps": []})
    assert r.status_code == 422 and r.json()["error"]["field"] == "samples", r.text
    long = {"kind": "include", "samples": samples.tolist(), "timestamps": (t_ns / 1e4).tolist()}
    r = http.post("/skills/pour/corrections", json=long)
    assert r.status_code == 422 and r.json()["error"]["field"] == "timestamps", r.text
    assert "time_unit" in r.json()["error"]["message"], r.text
    assert http.get("/skills/pour/models").json()["total"] == before

    r = http.post("/skills/pour/corrections/file", params={"kind": "include", "time_unit": "ns"},
                  content=csv.encode(), headers={"content-type": "text/csv"})
    assert r.status_code == 201, r.text
    r = http.post("/skills/pour/corrections", params={"time_unit": "ms"}, json=long)
    assert r.status_code == 201, r.text
    assert http.get("/skills/pour/corrections").json()["total"] == 2


def test_a_file_corrections_label_is_held_to_a_corrections_length(http: httpx.Client) -> None:
    # A multipart label of 201 characters was cut to 200 without a word; a long file name
    # is cut to its last 200 characters, as a demonstration's to its last 256.
    fitted = served_canal(http)
    rows = "x,y,z\n" + "".join(",".join(map(repr, r)) + "\n" for r in wider_path(fitted))
    r = http.post("/skills/pour/corrections/file", params={"kind": "include"},
                  files={"file": ("a.csv", rows.encode(), "text/csv"), "label": (None, "l" * 201)})
    assert r.status_code == 422, r.text
    error = r.json()["error"]
    assert error["field"] == "label" and "at most 200 characters without NUL, got 201 characters" in error["message"]
    long_name = "n" * 300 + ".csv"
    r = http.post("/skills/pour/corrections/file", params={"kind": "include"},
                  files={"file": (long_name, rows.encode(), "text/csv")})
    assert r.status_code == 201 and r.json()["correction"]["label"] == long_name[-200:], r.text


def test_a_json_body_sent_to_the_file_route_is_told_where_it_goes(http: httpx.Client) -> None:
    r = http.post("/skills/pour/corrections/file", params={"kind": "include"},
                  json={"kind": "include", "samples": [[0, 0, 0]] * 4})
    assert r.status_code == 415, r.text
    assert "a JSON correction goes to POST /skills/pour/corrections" in r.json()["error"]["message"]


def long_wider_path(canal: canal_core.Canal, k: int, n: int = 2000) -> list[list[float]]:
    """A long include path that wiggles inside the canal's sections 5..70 (many samples)."""
    t = np.linspace(0.0, 1.0, n)
    idx = (5 + t * 65).astype(int)
    side = canal.normals if k % 2 == 0 else canal.binormals
    return (canal.directrix[idx]
            + (0.3 * canal.radii[idx] * np.sin(40 * t + k))[:, None] * side[idx]).tolist()


def stored_canals(settings: Settings) -> dict[int, dict[str, object]]:
    db = Database(settings.resolved_database_url)
    try:
        with db.read() as s:
            return {int(v): c for v, c in s.execute(select(ModelVersion.version, ModelVersion.canal))}
    finally:
        db.dispose()


def test_each_correction_path_is_stored_once_and_a_version_names_it(
        any_db_settings: Settings) -> None:
    # Every model version stored every earlier correction's path in its canal: K corrections
    # of M samples took K^2 M of storage (1.6 GB for one skill of 45 long corrections).
    paths = {}
    with LiveServer(create_app(any_db_settings)) as server, \
            httpx.Client(base_url=server.url, timeout=120) as http:
        assert http.post("/skills", json={"name": "pour", "dim": 3}).status_code == 201
        for j in range(5):
            assert http.post("/skills/pour/demonstrations",
                             json={"positions": demo_positions(j).tolist()}).status_code == 201
        assert http.post("/skills/pour/fit", json={"n_samples": 80}).status_code == 201
        fitted = served_canal(http)
        for k in range(4):
            path = long_wider_path(fitted, k)
            r = http.post("/skills/pour/corrections",
                          json={"kind": "include", "samples": path, "weight": 0.05,
                                "timestamps": np.linspace(0, 4, len(path)).tolist()})
            assert r.status_code == 201, r.text
            paths[r.json()["correction"]["id"]] = path
        ids = list(paths)
        start = wider_path(fitted)[0]
        served = http.post("/skills/pour/reproductions", json={"start": start}).json()["positions"]
        served4 = http.post("/skills/pour/reproductions",
                            json={"start": start, "model": 4}).json()["positions"]
        # the served model is the canal_core model dict; each correction names its stored
        # correction, whose path is one request away
        model = http.get("/skills/pour/models/latest", params={"serialized": True}).json()
        canal = canal_core.Canal.from_dict(model["serialized"])
        np.testing.assert_allclose(canal.reproduce(np.array(start)), served, atol=1e-9)
        assert [c["correction_id"] for c in model["serialized"]["corrections"]] == ids
        for cid, path in paths.items():
            r = http.get(f"/skills/pour/corrections/{cid}")
            assert r.status_code == 200, r.text
            assert r.json()["samples"] == path and len(r.json()["timestamps"]) == len(path)
        assert http.get("/skills/pour/corrections/99").status_code == 404
        refit = http.post("/skills/pour/fit", json={"n_samples": 80}).json()
        assert refit["corrections"] == ids
    one_path = len(json.dumps(paths[ids[0]]))
    canals = stored_canals(any_db_settings)
    sizes = {v: len(json.dumps(c)) for v, c in canals.items()}
    # version 5 holds four corrections: less than one path more than the fit it refines
    assert sizes[5] - sizes[1] < one_path, sizes
    assert sizes[7] - sizes[6] < one_path, sizes
    # A new process decodes the stored versions (its cache is empty): the same reproduction.
    with LiveServer(create_app(any_db_settings)) as server, \
            httpx.Client(base_url=server.url, timeout=120) as http:
        again = http.post("/skills/pour/reproductions",
                          json={"start": start, "model": 5}).json()["positions"]
        assert again == served
        # a version stored with its corrections' paths inside (as databases written before
        # paths were stored once hold them) is read as it is
        db = Database(any_db_settings.resolved_database_url)
        try:
            with db.write() as s:
                expanded = json.loads(json.dumps(canals[4]))
                for entry, path in zip(expanded["corrections"], paths.values(), strict=False):
                    entry.pop("correction_id")
                    entry["samples"] = path
                s.execute(update(ModelVersion).where(ModelVersion.version == 4)
                          .values(canal=expanded))
        finally:
            db.dispose()
        old = http.get("/skills/pour/models/4", params={"serialized": True}).json()["serialized"]
        assert [c["samples"] for c in old["corrections"]] == list(paths.values())[:3]
        assert http.post("/skills/pour/reproductions",
                         json={"start": start, "model": 4}).json()["positions"] == served4


def test_a_refit_counts_the_corrections_it_re_applies_in_its_cost(tmp_path) -> None:
    # Re-applying the corrections runs after the fit, holding the skill: 45 long corrections
    # took a refit past a minute, outside the fit's estimate and its cap.
    demos = [demo_positions(j) for j in range(5)]
    plain = FitJob(demos, None, None, None, {"n_samples": 80})
    kept = FitJob(demos, None, None, None, {"n_samples": 80}, None, [2000])
    runner = FitRunner(1e9)
    assert runner.check_cost(kept) == pytest.approx(
        runner.check_cost(plain) + reapply_cost_seconds([2000], 80))
    cap = runner.check_cost(plain) + 0.5 * reapply_cost_seconds([2000], 80)
    settings = Settings(data_dir=tmp_path / "data", recordings_enabled=False,
                        zenoh_enabled=False, fit_max_seconds=cap)
    with LiveServer(create_app(settings)) as server, \
            httpx.Client(base_url=server.url, timeout=60) as http:
        assert http.post("/skills", json={"name": "pour", "dim": 3}).status_code == 201
        for demo in demos:
            assert http.post("/skills/pour/demonstrations",
                             json={"positions": demo.tolist()}).status_code == 201
        assert http.post("/skills/pour/fit", json={"n_samples": 80}).status_code == 201
        path = long_wider_path(served_canal(http), 0)
        assert http.post("/skills/pour/corrections",
                         json={"kind": "include", "samples": path}).status_code == 201
        r = http.post("/skills/pour/fit", json={"n_samples": 80})
        assert r.status_code == 422, r.text
        error = r.json()["error"]
        assert error["type"] == "fit_too_slow" and "keep_corrections false" in error["message"]
        assert "1 correction of 2000 samples to re-apply" in error["message"]
        assert http.get("/skills/pour").json()["n_models"] == 2
        assert http.post("/skills/pour/fit",
                         json={"n_samples": 80, "keep_corrections": False}).status_code == 201
