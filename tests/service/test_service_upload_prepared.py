"""Uploads run canal_core's preparation stage, so what cannot be fitted is a 422 at
upload naming it, and raw robot logs (repeats, rounding-level steps, still ends) fit through REST."""

from __future__ import annotations

import io

import numpy as np
import pytest
from fastapi.testclient import TestClient
from raw_logs import raw_demo_set, ur5e_demos
from service_helpers import demo_positions
from test_service_uploads import ros2_mcap


def _error(r) -> dict:  # type: ignore[no-untyped-def]
    assert r.status_code == 422, r.text
    return r.json()["error"]


def test_identical_points_are_refused_at_upload(client: TestClient, skill: str) -> None:
    r = client.post(f"/skills/{skill}/demonstrations", json={"positions": [[0.1, 0.2, 0.3]] * 10})
    error = _error(r)
    assert error["field"] == "positions" and "identical" in error["message"]
    for j in range(2):  # the skill still fits: nothing unfittable was stored
        client.post(f"/skills/{skill}/demonstrations", json={"positions": demo_positions(j).tolist()})
    assert client.post(f"/skills/{skill}/fit", json={}).status_code == 201


def test_huge_finite_coordinates_are_refused_at_upload(client: TestClient, skill: str) -> None:
    r = client.post(f"/skills/{skill}/demonstrations",
                    json={"positions": (demo_positions(0) * 1e306).tolist()})
    error = _error(r)
    assert error["field"] == "positions" and "1e+15" in error["message"]


def test_raw_logs_fit_by_arc_length_and_by_time(client: TestClient, skill: str) -> None:
    logs = raw_demo_set("task1", seed=5, n_demos=4, rate_hz=200.0)
    for g in logs:
        r = client.post(f"/skills/{skill}/demonstrations",
                        json={"positions": g.positions.tolist(), "timestamps": g.timestamps.tolist()})
        assert r.status_code == 201, r.text
    for by_time in (False, True):
        r = client.post(f"/skills/{skill}/fit", json={"by_time": by_time, "n_samples": 200})
        assert r.status_code == 201, r.text
    start = np.mean([g.positions[0] for g in logs], axis=0).tolist()
    r = client.post(f"/skills/{skill}/reproductions", json={"start": start})
    assert r.status_code == 200, r.text


def _csv(times: np.ndarray, positions: np.ndarray, quats: np.ndarray) -> bytes:
    rows = np.column_stack([times, positions, quats])
    return ("t,x,y,z,qx,qy,qz,qw\n" + "\n".join(",".join(repr(float(v)) for v in r)
                                               for r in rows)).encode()


def test_real_logs_with_equal_and_late_stamps_upload_and_fit_as_the_clean_ones(
        client: TestClient, skill: str) -> None:
    # The real UR5e demos as a polling logger twice their rate writes them: every row twice,
    # stamp and all. The upload refused them before ("expected strictly increasing
    # timestamps, got duplicate value"), though the fit repairs equal stamps.
    positions, times, quats = ur5e_demos()
    assert client.post("/skills", json={"name": "clean", "dim": 3}).status_code == 201
    for j, (p, t, q) in enumerate(zip(positions, times, quats, strict=True)):
        twice = np.repeat(np.arange(t.size), 2)
        if j == 0:  # by file, as `canal demo add` sends an exported log
            r = client.post(f"/skills/{skill}/demonstrations",
                            files={"file": ("demo.csv", _csv(t[twice], p[twice], q[twice]))})
        else:
            r = client.post(f"/skills/{skill}/demonstrations", json={
                "positions": p[twice].tolist(), "timestamps": t[twice].tolist(),
                "orientations": q[twice].tolist()})
        assert r.status_code == 201, r.text
        stored = client.get(f"/skills/{skill}/demonstrations/{r.json()['id']}").json()
        assert stored["n_points"] == 2 * t.size
        assert np.array_equal(stored["timestamps"], t[twice])  # kept as sent
        r = client.post("/skills/clean/demonstrations", json={
            "positions": p.tolist(), "timestamps": t.tolist(), "orientations": q.tolist()})
        assert r.status_code == 201, r.text
    start = (positions[0][0] + 0.005).tolist()
    for by_time in (False, True):
        answers = []
        for name in (skill, "clean"):
            r = client.post(f"/skills/{name}/fit", json={"by_time": by_time, "n_samples": 200})
            assert r.status_code == 201, r.text
            r = client.post(f"/skills/{name}/reproductions", json={"start": start})
            assert r.status_code == 200, r.text
            answers.append(np.array(r.json()["positions"]))
        # the repeats carry nothing: the same canal, the same reproduction
        np.testing.assert_allclose(answers[0], answers[1], rtol=0, atol=1e-12)


def test_an_isolated_late_stamp_is_accepted_and_a_clock_reset_is_refused_naming_it(
        client: TestClient, skill: str) -> None:
    positions, times, _ = ur5e_demos()
    p, t = positions[1], times[1].copy()
    t[500], t[501] = t[501], t[500]  # one sample stamped late: the fit drops it
    r = client.post(f"/skills/{skill}/demonstrations",
                    json={"positions": p.tolist(), "timestamps": t.tolist()})
    assert r.status_code == 201, r.text
    reset = times[1].copy()
    reset[1000:] -= reset[1000]  # the clock restarts at 0 halfway: refused, nothing stored
    r = client.post(f"/skills/{skill}/demonstrations",
                    json={"positions": p.tolist(), "timestamps": reset.tolist()})
    error = _error(r)
    assert error["field"] == "timestamps"
    assert "time goes back for more than one sample" in error["message"]
    assert "at sample 1000" in error["message"]
    assert client.get(f"/skills/{skill}/demonstrations").json()["total"] == 1


def _ns_csv(times_s: np.ndarray, positions: np.ndarray) -> bytes:
    # a ROS log's stamps: integer nanoseconds since the epoch
    ns = (1_733_000_000 + times_s) * 1e9
    return ("timestamp,x,y,z\n" + "\n".join(
        f"{int(a)},{p[0]!r},{p[1]!r},{p[2]!r}" for a, p in zip(ns, positions.tolist(), strict=True)
    )).encode()


def test_nanosecond_stamps_are_refused_as_seconds_and_taken_with_their_unit(
        client: TestClient, skill: str) -> None:
    # A CSV with a ROS log's nanosecond stamps was stored as seconds: a 12 s demo lasted
    # 1.2e10 s (380 years), and so did every reproduction of a by-time fit.
    positions, times, _ = ur5e_demos()
    data = _ns_csv(times[0], positions[0])
    r = client.post(f"/skills/{skill}/demonstrations", files={"file": ("run.csv", data)})
    error = _error(r)
    assert error["field"] == "timestamps"
    span_ns = (times[0][-1] - times[0][0]) * 1e9
    assert f"span of {span_ns:.3g} s" in error["message"]
    assert "?time_unit=ms, us or ns" in error["message"]
    assert client.get(f"/skills/{skill}/demonstrations").json()["total"] == 0
    assert client.post("/skills", json={"name": "secs", "dim": 3}).status_code == 201
    for j in range(3):
        r = client.post(f"/skills/{skill}/demonstrations?time_unit=ns",
                        files={"file": ("run.csv", _ns_csv(times[j], positions[j]))})
        assert r.status_code == 201, r.text
        stored = client.get(f"/skills/{skill}/demonstrations/{r.json()['id']}").json()
        # seconds from the first sample, to the resolution of a float64 epoch in ns (256 ns)
        np.testing.assert_allclose(stored["timestamps"], times[j] - times[j][0], rtol=0, atol=1e-6)
        r = client.post("/skills/secs/demonstrations",
                        json={"positions": positions[j].tolist(), "timestamps": times[j].tolist()})
        assert r.status_code == 201, r.text
    durations = []
    for name in (skill, "secs"):
        assert client.post(f"/skills/{name}/fit", json={"by_time": True}).status_code == 201
        r = client.post(f"/skills/{name}/reproductions", json={"start": positions[0][0].tolist()})
        assert r.status_code == 200, r.text
        durations.append(r.json()["times"][-1])
    assert 2.0 < durations[0] < 20.0  # seconds, as the demos lasted
    assert durations[0] == pytest.approx(durations[1], rel=1e-6)


def test_time_unit_for_json_and_where_it_does_not_apply(client: TestClient, skill: str) -> None:
    positions, times, _ = ur5e_demos()
    ms = ((times[1] - times[1][0]) * 1e3).tolist()
    r = client.post(f"/skills/{skill}/demonstrations?time_unit=ms",
                    json={"positions": positions[1].tolist(), "timestamps": ms})
    assert r.status_code == 201, r.text
    stored = client.get(f"/skills/{skill}/demonstrations/{r.json()['id']}").json()
    np.testing.assert_allclose(stored["timestamps"], times[1] - times[1][0], atol=1e-9)
    # tried: a unit for a file without a time column, an MCAP file, an unknown unit
    r = client.post(f"/skills/{skill}/demonstrations?time_unit=ns",
                    files={"file": ("run.csv", b"x,y,z\n0,0,0\n1,0,0\n2,1,0\n3,1,1\n")})
    assert _error(r)["field"] == "time_unit"
    r = client.post(f"/skills/{skill}/demonstrations?time_unit=ns",
                    files={"file": ("run.mcap", ros2_mcap(positions[1][:50]))})
    assert _error(r)["field"] == "time_unit"
    r = client.post(f"/skills/{skill}/demonstrations?time_unit=minutes",
                    json={"positions": positions[1].tolist(), "timestamps": ms})
    assert r.status_code == 422 and "time_unit" in r.text
    assert client.get(f"/skills/{skill}/demonstrations").json()["total"] == 1



@pytest.mark.parametrize(("name", "scale"), [
    ("timestamp_ms", 1e3), ("time_ms", 1e3), ("t_us", 1e6), ("stamp_ns", 1e9), ("time_s", 1.0),
    ("time [ms]", 1e3), ("time (ms)", 1e3), ("Time[ms]", 1e3), ("time_usec", 1e6),
    ("timestamp_sec", 1.0), ("time [seconds]", 1.0), ("t_millis", 1e3), ("stamp_nanoseconds", 1e9)])
def test_a_time_column_that_names_its_unit_is_read_in_that_unit(client: TestClient, skill: str,
                                                                 name: str, scale: float) -> None:
    # A logger's "timestamp_ms" column used to be dropped without a word: the demonstration
    # was stored untimed although its file said when every sample was taken.
    p = demo_positions(1, n=12)
    t = np.arange(12) * 0.1
    lines = [f"{name},x,y,z"] + [",".join(repr(float(v)) for v in (tt * scale, *row))
                                 for tt, row in zip(t, p, strict=True)]
    r = client.post(f"/skills/{skill}/demonstrations",
                    files={"file": ("log.csv", "\n".join(lines).encode(), "text/csv")})
    assert r.status_code == 201, r.text
    back = client.get(f"/skills/{skill}/demonstrations/{r.json()['id']}").json()
    assert back["timestamps"] is not None, name
    np.testing.assert_allclose(back["timestamps"], t, atol=1e-9)
    np.testing.assert_array_equal(back["positions"], p)


@pytest.mark.parametrize("name", ["time [min]", "time_min", "t [h]", "timestamp (hours)"])
def test_a_time_column_in_a_unit_not_read_is_refused_not_dropped(client: TestClient, skill: str,
                                                                 name: str) -> None:
    # "time [min]" was not a time name: the file was stored untimed without a word.
    body = (f"{name},x,y,z\n0,0,0,0\n1,1,0,0\n2,2,1,0\n3,3,1,1\n").encode()
    error = _error(client.post(f"/skills/{skill}/demonstrations", files={"file": ("log.csv", body)}))
    assert error["field"] == "file:header" and repr(name) in error["message"], error
    assert client.get(f"/skills/{skill}/demonstrations").json()["total"] == 0


def test_a_time_column_with_a_unit_and_another_time_column_is_refused(client: TestClient,
                                                                      skill: str) -> None:
    body = b"t,time_ms,x,y,z\n0,0,0,0,0\n1,1000,1,0,0\n2,2000,2,1,0\n3,3000,3,1,1\n"
    error = _error(client.post(f"/skills/{skill}/demonstrations", files={"file": ("log.csv", body)}))
    assert error["field"] == "file:header" and "t, time_ms" in error["message"]
    assert client.get(f"/skills/{skill}/demonstrations").json()["total"] == 0

@pytest.mark.parametrize("columns", ["t,x,y,z", "x,y,z", "t,x,y,z,qx,qy,qz,qw"])
def test_numpys_savetxt_header_is_read(client: TestClient, skill: str, columns: str) -> None:
    # np.savetxt(path, a, delimiter=",", header="t,x,y,z") writes "# t,x,y,z": numpy's own
    # default. Its header used to be refused ("got # x, y, z"), and with a time column the
    # file was stored untimed, "# t" not being a time name.
    p = demo_positions(1, n=12)
    t = np.arange(12) * 0.1
    table = np.column_stack([t, p]) if columns.startswith("t,") else p
    if columns.endswith("qw"):
        table = np.column_stack([table, np.tile([0.0, 0.0, 0.0, 1.0], (12, 1))])
    buf = io.BytesIO()
    np.savetxt(buf, table, delimiter=",", header=columns)
    assert buf.getvalue().startswith(f"# {columns}\n".encode())
    r = client.post(f"/skills/{skill}/demonstrations",
                    files={"file": ("demo.csv", buf.getvalue(), "text/csv")})
    assert r.status_code == 201, r.text
    back = client.get(f"/skills/{skill}/demonstrations/{r.json()['id']}").json()
    np.testing.assert_allclose(back["positions"], p, rtol=1e-15)
    assert (back["timestamps"] is not None) == columns.startswith("t,")
    assert (back["orientations"] is not None) == columns.endswith("qw")


def test_comment_lines_before_the_header_or_the_data_are_skipped(client: TestClient, skill: str) -> None:
    p = demo_positions(1, n=12)
    rows = "\n".join(",".join(repr(float(v)) for v in row) for row in p)
    for body in (f"# robot: ur5e\n# rate: 125 Hz\nx,y,z\n{rows}\n",
                 f"# recorded on the bench\n{rows}\n",          # no header: bare columns
                 f"# robot: ur5e\n#x,y,z\n{rows}\n"):
        r = client.post(f"/skills/{skill}/demonstrations",
                        files={"file": ("demo.csv", body.encode(), "text/csv")})
        assert r.status_code == 201, (body[:40], r.text)
        back = client.get(f"/skills/{skill}/demonstrations/{r.json()['id']}").json()
        np.testing.assert_array_equal(back["positions"], p)
    # A commented line that names no columns the skill has is a comment, not a header.
    body = f"# t,u,v,w\n{rows}\n"
    r = client.post(f"/skills/{skill}/demonstrations", files={"file": ("demo.csv", body.encode())})
    assert r.status_code == 201, r.text


def _rostopic_csv(times_s: np.ndarray, positions: np.ndarray, quats: np.ndarray) -> bytes:
    """What `rostopic echo -p /ee_pose > run.csv` writes for a PoseStamped topic."""
    stamp = 1_733_000_000_000_000_000 + np.round(times_s * 1e9).astype(np.int64)
    record = stamp + 1_500_000  # received 1.5 ms after the stamp
    head = ("%time,field.header.seq,field.header.stamp,field.header.frame_id,"
            "field.pose.position.x,field.pose.position.y,field.pose.position.z,"
            "field.pose.orientation.x,field.pose.orientation.y,field.pose.orientation.z,"
            "field.pose.orientation.w")
    rows = [f"{r},{k},{s},base_link,{p[0]!r},{p[1]!r},{p[2]!r},{q[0]!r},{q[1]!r},{q[2]!r},{q[3]!r}"
            for k, (r, s, p, q) in enumerate(zip(record.tolist(), stamp.tolist(),
                                                 positions.tolist(), quats.tolist(), strict=True))]
    return (head + "\n" + "\n".join(rows) + "\n").encode()


def test_ros_csv_exports_upload_as_they_are(client: TestClient, skill: str) -> None:
    # rostopic's CSV (a frame_id text column, nanosecond stamps) and PlotJuggler's
    # (slash-separated names, __time in seconds) were refused: "expected CSV header columns
    # x, y, z", and the frame_id text would have failed the number parse.
    positions, times, quats = ur5e_demos()
    for j in range(2):
        r = client.post(f"/skills/{skill}/demonstrations",
                        files={"file": ("run.csv", _rostopic_csv(times[j], positions[j], quats[j]))})
        assert r.status_code == 201, r.text
        stored = client.get(f"/skills/{skill}/demonstrations/{r.json()['id']}").json()
        np.testing.assert_array_equal(stored["positions"], positions[j])
        np.testing.assert_allclose(stored["orientations"], quats[j])
        # the message stamps (not the record time), in seconds from the first
        np.testing.assert_allclose(stored["timestamps"], times[j] - times[j][0], atol=1e-6)
    pj = "__time,/ee_pose/pose/position/x,/ee_pose/pose/position/y,/ee_pose/pose/position/z\n"
    pj += "\n".join(f"{1_733_000_000 + t!r},{p[0]!r},{p[1]!r},{p[2]!r}"
                    for t, p in zip(times[2].tolist(), positions[2].tolist(), strict=True))
    r = client.post(f"/skills/{skill}/demonstrations", files={"file": ("pj.csv", pj.encode())})
    assert r.status_code == 201, r.text
    stored = client.get(f"/skills/{skill}/demonstrations/{r.json()['id']}").json()
    np.testing.assert_allclose(np.diff(stored["timestamps"]), np.diff(times[2]), atol=1e-6)
    r = client.post(f"/skills/{skill}/fit", json={"by_time": True})
    assert r.status_code == 201, r.text
    # tried: two poses in one export (two position.x columns), an orientation without w
    two = b"a.position.x,a.position.y,a.position.z,b.position.x\n" + b"1,2,3,4\n" * 5
    error = _error(client.post(f"/skills/{skill}/demonstrations", files={"file": ("t.csv", two)}))
    assert error["field"] == "file:header" and "a.position.x, b.position.x" in error["message"]
    no_w = (b"x,y,z,pose.orientation.x,pose.orientation.y,pose.orientation.z\n"
            + b"\n".join(f"{k},0,0,0,0,0".encode() for k in range(6)))
    error = _error(client.post(f"/skills/{skill}/demonstrations", files={"file": ("t.csv", no_w)}))
    assert error["field"] == "file:header" and "orientation" in error["message"]
    # what came is named: the columns found, and the one missing
    assert error["message"].endswith("got pose.orientation.x, pose.orientation.y, "
                                     "pose.orientation.z (no qw)"), error
    twice = b"x,y,z,qx,qy,qz,qw,pose.orientation.w\n" + b"0,0,0,0,0,0,1,1\n" * 5
    error = _error(client.post(f"/skills/{skill}/demonstrations", files={"file": ("t.csv", twice)}))
    assert error["message"].endswith("got qx, qy, qz, qw, pose.orientation.w (qw twice)"), error
    assert client.get(f"/skills/{skill}/demonstrations").json()["total"] == 3


def test_ur_rtde_recordings_and_other_delimiters_upload_as_they_are(
        client: TestClient, skill: str) -> None:
    # UR's RTDE recorder (record.py) writes space-separated columns: timestamp and
    # actual_TCP_pose_0..5, the pose as x, y, z and an axis-angle rotation vector. It was
    # refused ("expected CSV header columns x, y, z"), as were tab- and ;-separated files.
    from scipy.spatial.transform import Rotation

    positions, times, quats = ur5e_demos()
    p, t, q = positions[0], times[0], quats[0]
    rotvec = Rotation.from_quat(q).as_rotvec()
    head = "timestamp " + " ".join(f"actual_TCP_pose_{k}" for k in range(6)) + " actual_q_0"
    rows = [" ".join(repr(v) for v in (ti, *pi, *ri, 0.5)) for ti, pi, ri in
            zip(t.tolist(), p.tolist(), rotvec.tolist(), strict=True)]
    r = client.post(f"/skills/{skill}/demonstrations",
                    files={"file": ("robot_data.csv", ("\n".join([head, *rows]) + "\n").encode())})
    assert r.status_code == 201, r.text
    stored = client.get(f"/skills/{skill}/demonstrations/{r.json()['id']}").json()
    np.testing.assert_array_equal(stored["positions"], p)
    np.testing.assert_array_equal(stored["timestamps"], t)
    back = Rotation.from_quat(stored["orientations"])
    assert (back * Rotation.from_quat(q).inv()).magnitude().max() < 1e-9  # q and -q alike
    for sep in ("\t", ";"):
        text = sep.join(["t", "x", "y", "z"]) + "\n" + "\n".join(
            sep.join(repr(v) for v in (ti, *pi)) for ti, pi in zip(times[1].tolist(),
                                                                    positions[1].tolist(),
                                                                    strict=True))
        r = client.post(f"/skills/{skill}/demonstrations", files={"file": ("run.csv", text.encode())})
        assert r.status_code == 201, (repr(sep), r.text)
        stored = client.get(f"/skills/{skill}/demonstrations/{r.json()['id']}").json()
        np.testing.assert_array_equal(stored["positions"], positions[1])
    # tried: a space-separated file with a word in a number column (named by its line)
    bad = b"t x y z\n0 0 0 0\n1 1 zero 0\n2 2 0 0\n3 3 1 0\n"
    error = _error(client.post(f"/skills/{skill}/demonstrations", files={"file": ("b.csv", bad)}))
    assert error["field"] == "file:line 3" and "zero" in error["message"]
    assert client.get(f"/skills/{skill}/demonstrations").json()["total"] == 3


def test_a_ragged_row_is_named_also_where_only_some_columns_are_read(
        client: TestClient, skill: str) -> None:
    # tried: a rostopic-style file (a text column, so only the pose columns are read) whose
    # third line has one cell too many, then one cell too few
    head = b"field.header.frame_id,field.pose.position.x,field.pose.position.y,field.pose.position.z\n"
    good = [b"base,%d,%d,0" % (k, k * k) for k in range(6)]
    for bad in (b"base,2,4,0,9", b"base,2,4"):
        rows = [*good[:2], bad, *good[3:]]
        data = head + b"\n".join(rows) + b"\n"
        error = _error(client.post(f"/skills/{skill}/demonstrations",
                                   files={"file": ("r.csv", data)}))
        assert error["field"] == "file:line 4", error
    r = client.post(f"/skills/{skill}/demonstrations",
                    files={"file": ("r.csv", head + b"\n".join(good) + b"\n")})
    assert r.status_code == 201, r.text


def test_stamps_spanning_less_than_a_control_tick_are_refused(live_server) -> None:  # type: ignore[no-untyped-def]
    # Stamps spanning 1e-12 s were stored, and a by-time fit reproduced the motion in 1e-7 s
    # at 1e7 m/s, although a reproduction's own duration below 1 ms is refused.
    import httpx

    with httpx.Client(base_url=live_server.url, timeout=60) as http:
        assert http.post("/skills", json={"name": "tick", "dim": 3}).status_code == 201
        positions = demo_positions(0)
        n = positions.shape[0]
        for span in (1e-12, 5e-4):
            r = http.post("/skills/tick/demonstrations",
                          json={"positions": positions.tolist(),
                                "timestamps": np.linspace(0.0, span, n).tolist()})
            error = _error(r)
            assert error["field"] == "timestamps", error
            assert "at least 0.001 s" in error["message"], error
            assert f"span of {span:.3g} s" in error["message"], error
        # a file: the time column read in the unit it is said to be in (seconds sent as ns)
        csv = "t,x,y,z\n" + "\n".join(
            f"{float(t)!r},{p[0]!r},{p[1]!r},{p[2]!r}"
            for t, p in zip(np.linspace(0.0, 2.0, n), positions.tolist(), strict=True))
        r = http.post("/skills/tick/demonstrations?time_unit=ns",
                      files={"file": ("run.csv", csv.encode())})
        error = _error(r)
        assert error["field"] == "timestamps" and "at least 0.001 s" in error["message"], error
        assert http.get("/skills/tick/demonstrations").json()["total"] == 0
        # from one control tick on, stamps are taken
        for j, span in enumerate((1e-3, 2.0)):
            r = http.post("/skills/tick/demonstrations",
                          json={"positions": demo_positions(j).tolist(),
                                "timestamps": np.linspace(0.0, span, n).tolist()})
            assert r.status_code == 201, r.text
        r = http.post("/skills/tick/demonstrations", files={"file": ("run.csv", csv.encode())})
        assert r.status_code == 201, r.text
