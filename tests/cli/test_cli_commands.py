"""``canal`` end to end: every command on real files against a real service on loopback."""

from __future__ import annotations

import json
import os
import re
import socket
import subprocess
import sys
import time
import typing
from collections.abc import Callable
from pathlib import Path

import httpx
import numpy as np
import pytest
from canal_client import CanalClient
from canal_client.cli.models import field_bounds
from canal_client.cli.serve import SERVICE_INSTALL
from canal_live import (
    MCAP_MAGIC,
    RRD_MAGIC,
    LiveService,
    closed_port_url,
    demo_positions,
    free_port,
    other_web_app,
    write_demo_files,
)
from canal_testing import ROUTE_STARTS, two_route_demo
from click.testing import Result
from mcap.reader import make_reader

from canal_core.options import ALIGNMENTS, CROSS_SECTIONS, DIRECTRICES, FRAMES, PERSISTENCES
from canal_protocol.options import MAX_CORRECTION_LABEL, MAX_DEMO_LABEL
from canal_protocol.schemas import MAX_ID, FitRequest, ReproductionRequest

Run = Callable[..., Result]  # the `run` fixture (conftest.py)

#: What the CLI must run without: the service and the dependencies only the service has.
SERVICE_ONLY = ("canal_service", "fastapi", "uvicorn", "sqlalchemy", "alembic", "psycopg",
                "rerun", "mcap", "starlette", "prometheus_client")


def make_fitted(service: LiveService, name: str, n: int = 4) -> None:
    with CanalClient(service.url) as c:
        c.create_skill(name)
        for j in range(n):
            c.add_demo(name, demo_positions(j))
        c.fit(name, n_samples=30)


def test_skill_create_list_show_delete(run: Run, unique_name: Callable[[str], str]) -> None:
    name = unique_name("pour")
    r = run("skill", "create", name, "--dim", "2", "--description", "pour water")
    assert r.exit_code == 0, r.output
    assert f"created skill {name} (2-D)" in r.stdout

    r = run("skill", "list")
    assert r.exit_code == 0 and name in r.stdout and "pour water" in r.stdout
    r = run("--json", "skill", "list")
    listed = {s["name"]: s for s in json.loads(r.stdout)}
    assert listed[name]["dim"] == 2 and listed[name]["n_demonstrations"] == 0

    r = run("skill", "show", name)
    assert r.exit_code == 0 and "not fitted yet" in r.stdout and "2-D" in r.stdout
    shown = json.loads(run("--json", "skill", "show", name).stdout)
    assert shown["skill"]["name"] == name and shown["models"] == []

    # a duplicate is the service's 409, printed, exit 1
    r = run("skill", "create", name)
    assert r.exit_code == 1 and r.stderr.startswith("error: ") and name in r.stderr

    # delete asks first; "n" aborts and keeps the skill
    r = run("skill", "delete", name, input="n\n")
    assert r.exit_code == 1 and "Aborted" in r.output
    assert run("skill", "show", name).exit_code == 0
    r = run("skill", "delete", name, "--yes")
    assert r.exit_code == 0 and f"deleted skill {name}" in r.stdout
    r = run("skill", "show", name)
    assert r.exit_code == 1
    assert r.stderr.strip() == f"error: no skill named '{name}' (field: name)"
    assert r.stdout == "" and "Traceback" not in r.output


def test_demo_add_files_and_a_folder_with_a_bad_file(
        run: Run, unique_name: Callable[[str], str], tmp_path: Path) -> None:
    name = unique_name("demos")
    assert run("skill", "create", name).exit_code == 0
    files = write_demo_files(tmp_path / "demos")

    # one file of each format, given by name
    r = run("demo", "add", name, str(files["csv"]), str(files["npy"]), "--label", "given")
    assert r.exit_code == 0, r.output
    assert "a_demo.csv: id " in r.stdout and "b_demo.npy: id " in r.stdout
    r = run("--json", "demo", "add", name, str(files["mcap"]), "--topic", "/ee_pose")
    assert r.exit_code == 0, r.output
    [added] = json.loads(r.stdout)
    assert added["n_points"] == 40 and added["file"].endswith("d_demo.mcap")

    # a folder: every supported file in name order, one broken; the others are still added
    (tmp_path / "demos" / "c_broken.csv").write_text("x,y,z\n1,2\n")
    (tmp_path / "demos" / "notes.txt").write_text("not a demonstration")
    r = run("demo", "add", name, str(tmp_path / "demos"))
    assert r.exit_code == 1
    order = [line.split(":")[0] for line in r.stdout.splitlines() if ": id " in line]
    assert order == ["a_demo.csv", "b_demo.npy", "c_demo.json", "d_demo.mcap"]
    broken = tmp_path / "demos" / "c_broken.csv"
    assert f"error: {broken}: " in r.stderr and "notes.txt" not in r.output
    assert "added 4 of 5 demonstrations" in r.stdout

    r = run("--json", "demo", "list", name)
    demos = json.loads(r.stdout)
    assert len(demos) == 7
    assert [d["source"] for d in demos] == ["csv", "npy", "mcap", "csv", "npy", "json", "mcap"]
    assert demos[0]["label"] == "given" and demos[0]["has_timestamps"]
    r = run("demo", "list", name)
    assert r.exit_code == 0 and "given" in r.stdout and "mcap" in r.stdout

    # rm: every id is tried; an unknown one is reported and makes the exit code 1
    ids = [str(d["id"]) for d in demos[:2]]
    r = run("demo", "rm", name, ids[0], "999999", ids[1])
    assert r.exit_code == 1
    assert f"removed demonstration {ids[0]}" in r.stdout
    assert f"removed demonstration {ids[1]}" in r.stdout
    assert "error: demonstration 999999: " in r.stderr
    assert len(json.loads(run("--json", "demo", "list", name).stdout)) == 5


def test_demo_add_errors(run: Run, unique_name: Callable[[str], str], tmp_path: Path) -> None:
    files = write_demo_files(tmp_path)
    r = run("demo", "add", "no-such-skill", str(files["csv"]))
    assert r.exit_code == 1 and "no skill named 'no-such-skill'" in r.stderr
    name = unique_name("bad")
    run("skill", "create", name)
    bad = tmp_path / "nan.csv"
    bad.write_text("x,y,z\n0,0,0\n1,nan,0\n2,0,0\n3,0,0\n")
    r = run("demo", "add", name, str(bad))
    assert r.exit_code == 1 and r.stderr.startswith(f"error: {bad}: ")
    assert "finite" in r.stderr or "nan" in r.stderr.lower()
    odd = tmp_path / "demo.xyz"
    odd.write_text("1,2,3\n")
    r = run("demo", "add", name, str(odd), str(files["npy"]))
    assert r.exit_code == 1
    assert f"error: {odd}: unsupported file type" in r.stderr
    assert "b_demo.npy: id " in r.stdout
    # a missing file is bad usage, refused before anything is uploaded
    r = run("demo", "add", name, str(files["csv"]), str(tmp_path / "missing.csv"))
    assert r.exit_code == 2 and f"no file {str(tmp_path / 'missing.csv')!r}" in r.output
    assert len(json.loads(run("--json", "demo", "list", name).stdout)) == 1
    # a 2-D file into a 3-D skill: the service's message names the field
    two_d = write_demo_files(tmp_path / "2d", dim=2)
    r = run("demo", "add", name, str(two_d["npy"]))
    assert r.exit_code == 1 and "(field: " in r.stderr


def test_demo_add_says_which_flag_takes_nanosecond_stamps(
        run: Run, service: LiveService, unique_name: Callable[[str], str], tmp_path: Path) -> None:
    # a ROS log exported to CSV: integer nanoseconds since the epoch, 100 Hz for 2 s
    name = unique_name("ns")
    run("skill", "create", name)
    positions = demo_positions(0, n=200)
    stamps = 1_733_000_000_000_000_000 + np.arange(200) * 10_000_000
    log = tmp_path / "ros.csv"
    log.write_text("timestamp,x,y,z\n" + "".join(
        f"{t},{p[0]!r},{p[1]!r},{p[2]!r}\n" for t, p in zip(stamps.tolist(), positions.tolist(),
                                                              strict=True)))
    r = run("demo", "add", name, str(log))
    assert r.exit_code == 1 and "--time-unit ms, us or ns" in r.stderr, r.stderr
    assert "?time_unit" not in r.stderr
    r = run("--json", "demo", "add", name, str(log), "--time-unit", "ns")
    assert r.exit_code == 0, r.output
    demo_id = json.loads(r.stdout)[0]["id"]
    with CanalClient(service.url) as c:  # stored as seconds from the first sample
        times = c.get_demo(name, demo_id).timestamps
    assert times is not None and times[0] == 0.0 and abs(times[-1] - 1.99) < 1e-6


def test_fit_and_reproduce_to_files(run: Run, service: LiveService,
                                    unique_name: Callable[[str], str], tmp_path: Path) -> None:
    name = unique_name("fit")
    run("skill", "create", name)
    r = run("fit", name)
    assert r.exit_code == 1 and "error: " in r.stderr  # no demonstrations yet (409)
    for j in range(4):
        np.save(tmp_path / f"d{j}.npy", demo_positions(j))
    assert run("demo", "add", name, str(tmp_path)).exit_code == 0

    r = run("fit", name, "--cross-section", "mec", "--samples", "25")
    assert r.exit_code == 0, r.output
    assert f"fitted {name}: version 1" in r.stdout and "25 mec sections" in r.stdout
    ids = [str(d["id"]) for d in json.loads(run("--json", "demo", "list", name).stdout)]
    r = run("--json", "fit", name, "--cross-section", "spline", "--frames", "frenet",
            "--alignment", "dtw", "--directrix", "mean", "--samples", "20",
            "--demo", ids[0], "--demo", ids[1], "--demo", ids[2], "--frame-smoothing", "0",
            "--by-time")
    assert r.exit_code == 0, r.output
    model = json.loads(r.stdout)
    assert model["version"] == 2 and model["demo_ids"] == [int(i) for i in ids[:3]]
    assert model["options"]["frames"] == "frenet" and model["options"]["alignment"] == "dtw"
    assert model["options"]["frame_smoothing"] == 0.0
    assert model["options"]["by_time"] is False  # .npy demos without a time column
    r = run("fit", name, "--cross-section", "hexagon")
    assert r.exit_code == 2 and "hexagon" in r.output

    with CanalClient(service.url) as c:
        reproduced = c.reproduce(name, [0.0, 0.01, 0.0], model=1)
    expected = reproduced.positions
    for suffix in ("csv", "npy", "json"):
        out = tmp_path / "out" / f"traj.{suffix}"
        r = run("reproduce", name, "--start", "0,0.01,0", "--model", "1", "--out", str(out))
        assert r.exit_code == 0, r.output
        assert "start inside" in r.stdout and f"wrote {out}" in r.stdout
        if reproduced.times is None:
            assert "the model is untimed" in r.stdout
        else:
            assert f"the trajectory lasts {reproduced.times[-1]:.3g} s" in r.stdout
        if suffix == "csv":
            table = np.loadtxt(out, delimiter=",", skiprows=1)
            if reproduced.times is None:
                assert out.read_text().splitlines()[0] == "x,y,z"
                got = table
            else:
                assert out.read_text().splitlines()[0] == "t,x,y,z"
                np.testing.assert_allclose(table[:, 0], reproduced.times)
                got = table[:, 1:]
        elif suffix == "npy":
            got = np.load(out)
        else:
            doc = json.loads(out.read_text())
            got = np.asarray(doc["positions"])
            assert doc["inside"] is True and doc["model_version"] == 1
        assert got.shape == expected.shape and np.allclose(got, expected)

    r = run("reproduce", name, "--start", "-0.3,0.01,0")  # behind the first plane
    assert r.exit_code == 0 and "points approach it in a straight line" in r.stdout, r.output
    r = run("--json", "reproduce", name, "--start", "-0.05,5,0")
    doc = json.loads(r.stdout)
    assert r.exit_code == 0 and doc["projected"] is True and doc["inside"] is False
    assert doc["ratios"][0] > 1.0 and len(doc["ratios"]) == len(doc["positions"])
    r = run("reproduce", name, "--start", "-0.05,5,0")
    assert r.exit_code == 0 and re.search(r"how far out, .*: start \d+\.\d\d, a quarter \d+\.\d\d, "
                                          r"half-way \d+\.\d\d, three quarters \d+\.\d\d, end 0\.00",
                                          r.stdout), r.output
    r = run("reproduce", name, "--start", "0,5,0", "--outside", "raise")
    assert r.exit_code == 1 and "(field: start)" in r.stderr
    with CanalClient(service.url) as c:
        kept = c.reproduce(name, [0.0, 0.01, 0.0], model=1, persistence="learned+end")
    r = run("--json", "reproduce", name, "--start", "0,0.01,0", "--model", "1",
            "--persistence", "learned+end")
    assert r.exit_code == 0 and np.allclose(json.loads(r.stdout)["positions"], kept.positions)
    for bad in ("1,2", "a,b,c", "1,2,3,4"):
        r = run("reproduce", name, "--start", bad)
        assert r.exit_code == (1 if bad == "1,2" else 2), r.output  # 1,2: the service's 422
    r = run("reproduce", name, "--start", "0,0,0", "--out", str(tmp_path / "t.txt"))
    assert r.exit_code == 2 and ".csv, .npy or .json" in r.output
    # a path that cannot be written (its parent is a file; a folder named like a file) was a
    # traceback ("FileExistsError", "IsADirectoryError")
    (tmp_path / "a-file").write_text("")
    (tmp_path / "folder.csv").mkdir()
    for blocked in (tmp_path / "a-file" / "t.csv", tmp_path / "folder.csv"):
        r = run("reproduce", name, "--start", "0,0.01,0", "--out", str(blocked))
        assert r.exit_code == 1 and "Traceback" not in r.output, r.output
        assert f"cannot write {blocked}" in r.output, r.output

    # --goal deforms the canal to end there, --duration times the path
    r = run("--json", "reproduce", name, "--start", "0,0.01,0", "--model", "1",
            "--goal", "1.05,0.02,0.1", "--duration", "2.5")
    assert r.exit_code == 0, r.output
    doc = json.loads(r.stdout)
    assert np.allclose(doc["positions"][-1], [1.05, 0.02, 0.1], atol=1e-9)
    assert abs(doc["times"][-1] - 2.5) < 1e-9 and len(doc["velocities"]) == len(doc["positions"])
    timed_csv = tmp_path / "timed.csv"
    r = run("reproduce", name, "--start", "0,0.01,0", "--duration", "3", "--out", str(timed_csv))
    assert r.exit_code == 0 and "the trajectory lasts 3 s" in r.stdout, r.output
    assert timed_csv.read_text().splitlines()[0] == "t,x,y,z"
    assert np.loadtxt(timed_csv, delimiter=",", skiprows=1)[-1, 0] == pytest.approx(3.0)
    for bad in (("--goal", "1,2,x"), ("--duration", "0"), ("--duration", "-1")):
        r = run("reproduce", name, "--start", "0,0,0", *bad)
        assert r.exit_code == 2 and bad[0] in r.output, r.output


def test_fit_routes_and_reproduce_print_the_route(run: Run, unique_name: Callable[[str], str],
                                                  tmp_path: Path) -> None:
    name = unique_name("routes")
    run("skill", "create", name)
    for j in range(8):
        np.save(tmp_path / f"d{j}.npy", two_route_demo(j))
    assert run("demo", "add", name, str(tmp_path)).exit_code == 0
    r = run("fit", name, "--samples", "40")
    assert r.exit_code == 0, r.output
    assert "2 routes, one canal each" in r.stdout
    start = ",".join(str(v) for v in ROUTE_STARTS[1])
    r = run("reproduce", name, "--start", start)
    assert r.exit_code == 0, r.output
    assert "followed route 1 (entry)" in r.stdout
    r = run("--json", "reproduce", name, "--start", start, "--route", "0")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["route"] == 0
    r = run("skill", "show", name)
    assert r.exit_code == 0 and "routes" in r.stdout
    # A way shown once is a route of its own, one demonstration, named in a note.
    s = np.linspace(0.0, 1.0, 120)
    np.save(tmp_path / "over.npy", np.column_stack([s, 0.1 * (1 - s), 0.5 * np.sin(np.pi * s)]))
    assert run("demo", "add", name, str(tmp_path / "over.npy")).exit_code == 0
    r = run("fit", name, "--samples", "40")
    assert r.exit_code == 0, r.output
    lone = re.search(r"; route 2: demo (\d+)\)", r.stdout)
    assert "3 routes, one canal each" in r.stdout and lone, r.stdout
    assert f"demonstration {lone[1]} goes a way of its own alone" in " ".join(r.stdout.split())
    r = run("--json", "fit", name, "--samples", "40", "--routes", "1")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["routes"] == 1
    r = run("reproduce", name, "--start", start)
    assert r.exit_code == 0 and "followed" not in r.stdout
    r = run("fit", name, "--routes", "0")
    assert r.exit_code == 2


def test_export_and_view(run: Run, service: LiveService, unique_name: Callable[[str], str],
                         tmp_path: Path) -> None:
    name = unique_name("rec")
    make_fitted(service, name)
    rrd, mcap = tmp_path / "x" / "rec.rrd", tmp_path / "rec.mcap"
    r = run("export", name, "--rrd", str(rrd), "--mcap", str(mcap))
    assert r.exit_code == 0, r.output
    assert f"wrote {rrd}" in r.stdout and f"wrote {mcap}" in r.stdout
    assert rrd.read_bytes().startswith(RRD_MAGIC)
    assert mcap.read_bytes().startswith(MCAP_MAGIC)
    with mcap.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics.message_count > 0
    assert {c.topic for c in summary.channels.values()}

    # neither flag: both, named after the skill, in the working folder
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        r = run("--json", "export", name)
    finally:
        os.chdir(cwd)
    assert json.loads(r.stdout) == {"rrd": f"{name}.rrd", "mcap": f"{name}.mcap"}
    assert (tmp_path / f"{name}.rrd").stat().st_size > 0

    # A folder is where the files go, named after the skill (as cp does); it was a traceback
    # ("IsADirectoryError") after the whole download.
    folder = tmp_path / "out"
    folder.mkdir()
    r = run("export", name, "--rrd", str(folder), "--mcap", str(folder))
    assert r.exit_code == 0, r.output
    assert (folder / f"{name}.rrd").read_bytes().startswith(RRD_MAGIC)
    assert (folder / f"{name}.mcap").read_bytes().startswith(MCAP_MAGIC)
    # a path that cannot be written: the reason, no traceback, nothing left behind
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    r = run("export", name, "--rrd", str(blocker / "x.rrd"))
    assert r.exit_code == 1 and "Traceback" not in r.output, r.output
    assert f"cannot write {blocker / 'x.rrd'}" in r.output, r.output
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.endswith(".part")) == []

    r = run("view", name, "--no-open")
    assert r.exit_code == 0, r.output
    cached = tmp_path / "cache" / f"{name}.rrd"
    assert f"recording saved to {cached}" in r.stdout
    assert "open it with: " in r.stdout and str(cached) in r.stdout.splitlines()[1]
    assert cached.read_bytes().startswith(RRD_MAGIC)
    # a download folder that cannot be made: the reason and the variable to set, no traceback
    for env in ({"CANAL_CACHE_DIR": str(blocker)}, {"CANAL_CACHE_DIR": "", "XDG_CACHE_HOME": str(blocker)}):
        r = run("view", name, "--no-open", env=env)
        assert r.exit_code == 1 and "Traceback" not in r.output, r.output
        assert f"cannot write {blocker}" in r.output and "CANAL_CACHE_DIR" in r.output, r.output
    # without a display nothing is spawned, even without --no-open
    r = run("--json", "view", name, env={"DISPLAY": "", "WAYLAND_DISPLAY": ""})
    doc = json.loads(r.stdout)
    if sys.platform.startswith("linux"):
        assert doc["opened"] is False and doc["command"].endswith(str(cached))

    r = run("export", "no-such-skill", "--rrd", str(tmp_path / "n.rrd"))
    assert r.exit_code == 1 and not (tmp_path / "n.rrd").exists()
    # --url at another web app: its page is not saved as the recording
    with other_web_app() as url:
        r = run("export", name, "--rrd", str(tmp_path / "w.rrd"), "--mcap",
                str(tmp_path / "w.mcap"), url=url)
    assert r.exit_code == 1 and "is not a Canal recording" in r.output, r.output
    assert not (tmp_path / "w.rrd").exists() and not (tmp_path / "w.mcap").exists()


def test_unreachable_service_exit_code_3(run: Run) -> None:
    url = closed_port_url()
    for args in (("skill", "list"), ("demo", "list", "x"), ("fit", "x"),
                 ("reproduce", "x", "--start", "0,0,0"), ("view", "x", "--no-open")):
        r = run(*args, url=url)
        assert r.exit_code == 3, (args, r.output)
        assert f"cannot reach the Canal service at {url}" in r.stderr
        assert "canal serve" in r.stderr and "Traceback" not in r.output


def test_token_is_sent(tmp_path: Path) -> None:
    from canal_client.cli import app
    from typer.testing import CliRunner

    with LiveService(tmp_path / "data", token="s3cret") as live:
        env = {"CANAL_URL": live.url, "CANAL_TOKEN": ""}
        r = CliRunner().invoke(app, ["skill", "list"], env=env)
        assert r.exit_code == 1 and "(field: Authorization)" in r.stderr
        r = CliRunner().invoke(app, ["--token", "s3cret", "skill", "create", "t"], env=env)
        assert r.exit_code == 0, r.output
        r = CliRunner().invoke(app, ["skill", "list"], env={**env, "CANAL_TOKEN": "s3cret"})
        assert r.exit_code == 0 and "t" in r.stdout


def test_a_token_no_header_can_carry_is_a_usage_error(tmp_path: Path) -> None:
    # A letter outside ASCII was a UnicodeEncodeError traceback; a newline or a trailing space
    # was exit 3 "cannot reach the Canal service ... Illegal header value".
    from canal_client.cli import app
    from typer.testing import CliRunner

    with LiveService(tmp_path / "data", token="s3cret") as live:
        env = {"CANAL_URL": live.url, "CANAL_TOKEN": ""}
        for token, got in (("tokén", "got 'é' at character 4 of 5"),
                           ("a\nb", "got '\\n' at character 2 of 3"),
                           ("s3cret ", "got a space at character 7 of 7")):
            for args, extra in ((["--token", token, "skill", "create", "t"], {}),
                                (["skill", "create", "t"], {"CANAL_TOKEN": token})):
                r = CliRunner().invoke(app, args, env={**env, **extra})
                said = " ".join(r.output.replace("│", " ").split())
                assert r.exit_code == 2, (token, extra, r.output)
                assert "--token (or CANAL_TOKEN)" in said and got in said, (token, said)
                assert "visible ASCII characters without spaces" in said, said
                assert "Traceback" not in r.output and "cannot reach" not in r.output
        r = CliRunner().invoke(app, ["--token", "s3cret", "--json", "skill", "list"], env=env)
        assert r.exit_code == 0 and json.loads(r.stdout) == [], r.output


def test_real_process_entry_point(service: LiveService, unique_name: Callable[[str], str],
                                  tmp_path: Path) -> None:
    name = unique_name("proc")
    np.save(tmp_path / "d.npy", demo_positions(0))
    cmd = [sys.executable, "-m", "canal_client.cli", "--url", service.url]
    env = {**os.environ, "CANAL_TOKEN": ""}
    p = subprocess.run([*cmd, "skill", "create", name], capture_output=True, text=True,
                       timeout=60, env=env)
    assert p.returncode == 0 and f"created skill {name}" in p.stdout, p.stderr
    p = subprocess.run([*cmd, "--json", "demo", "add", name, str(tmp_path / "d.npy")],
                       capture_output=True, text=True, timeout=60, env=env)
    assert p.returncode == 0 and json.loads(p.stdout)[0]["n_points"] == 40, p.stderr
    p = subprocess.run([*cmd, "skill", "show", "missing-skill"], capture_output=True,
                       text=True, timeout=60, env=env)
    assert p.returncode == 1 and "error: no skill named 'missing-skill'" in p.stderr
    assert "Traceback" not in p.stderr
    p = subprocess.run([sys.executable, "-m", "canal_client.cli", "--url", closed_port_url(),
                        "skill", "list"], capture_output=True, text=True, timeout=60, env=env)
    assert p.returncode == 3 and "Traceback" not in p.stderr
    assert "hint: start the service with 'canal serve'" in p.stderr
    script = Path(sys.executable).with_name("canal")  # [project.scripts] canal, when installed
    if script.exists():
        p = subprocess.run([str(script), "--url", service.url, "--json", "skill", "show", name],
                           capture_output=True, text=True, timeout=60, env=env)
        assert p.returncode == 0 and json.loads(p.stdout)["skill"]["n_demonstrations"] == 1


def test_serve_forwards_the_service_flags(tmp_path: Path) -> None:
    port = free_port()
    env = {**os.environ, "CANAL_TOKEN": ""}
    cmd = [sys.executable, "-m", "canal_client.cli", "serve", "--port", str(port),
           "--data-dir", str(tmp_path / "data"), "--no-recordings", "--no-zenoh",
           "--log-level", "warning"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    try:
        deadline = time.monotonic() + 60
        while True:
            assert proc.poll() is None, proc.communicate()[1][-2000:]
            try:
                health = httpx.get(f"http://127.0.0.1:{port}/healthz", timeout=2).json()
                if health["status"] != "starting":  # 503 starting while the app loads
                    break
            except httpx.TransportError:
                pass
            assert time.monotonic() < deadline, "canal serve did not start"
            time.sleep(0.2)
        assert health["status"] == "ok" and health["recorder"]["status"] == "disabled"
        assert (tmp_path / "data" / "canal.sqlite3").exists()
        cmdline = Path(f"/proc/{proc.pid}/cmdline")
        if cmdline.exists():  # the process became the service (exec): its signals, its code
            assert cmdline.read_bytes().split(b"\0")[1:3] == [b"-m", b"canal_service"]
    finally:
        proc.terminate()
        proc.communicate(timeout=30)
    p = subprocess.run([sys.executable, "-m", "canal_client.cli", "serve", "--help"],
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 0 and "--data-dir" in p.stdout and "--max-body-bytes" in p.stdout
    # a flag the service refuses: the service's own message and exit code (argparse's 2)
    p = subprocess.run([sys.executable, "-m", "canal_client.cli", "serve", "--port", "eighty"],
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and "python -m canal_service" in p.stderr
    assert "--port" in p.stderr and "eighty" in p.stderr
    # 'loud' was uvicorn's KeyError traceback, from the flag and from the variable alike
    for args, env in ((["--log-level", "loud"], {}), ([], {"CANAL_LOG_LEVEL": "loud"})):
        p = subprocess.run([sys.executable, "-m", "canal_client.cli", "serve", "--port",
                            str(free_port()), "--data-dir", str(tmp_path / "loud"),
                            "--no-recordings", "--no-zenoh", *args], capture_output=True,
                           text=True, timeout=60, env={**os.environ, **env})
        assert p.returncode == 2 and "Traceback" not in p.stderr, p.stderr[-2000:]
        assert "--log-level (or CANAL_LOG_LEVEL): Input should be 'debug', 'info'" in p.stderr
        assert "got 'loud'" in p.stderr


def test_serve_on_a_port_in_use_exits_saying_so(tmp_path: Path) -> None:
    # It printed "address already in use" and then hung for good, waiting for an app that
    # waited for the port: `make run` beside a running service looked like a service.
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        cmd = [sys.executable, "-m", "canal_client.cli", "serve", "--port", str(port),
               "--data-dir", str(tmp_path / "data"), "--no-recordings", "--no-zenoh"]
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=60,
                           env={**os.environ, "CANAL_TOKEN": ""})
    assert p.returncode != 0, p.stderr[-2000:]
    assert "address already in use" in p.stderr and str(port) in p.stderr, p.stderr[-2000:]
    assert "stop what uses that port, or pass --port" in p.stderr, p.stderr[-2000:]
    assert "Traceback" not in p.stderr, p.stderr[-2000:]


def test_serve_with_a_data_dir_that_is_a_file_says_so(tmp_path: Path) -> None:
    # It was a traceback ending in "FileExistsError" from pathlib.
    data = tmp_path / "data"
    data.write_text("")
    cmd = [sys.executable, "-m", "canal_client.cli", "serve", "--port", str(free_port()),
           "--data-dir", str(data), "--no-recordings", "--no-zenoh"]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=60,
                       env={**os.environ, "CANAL_TOKEN": ""})
    assert p.returncode != 0 and "Traceback" not in p.stderr, p.stderr[-2000:]
    assert f"canal service: cannot use --data-dir {data}: " in p.stderr, p.stderr[-2000:]


def test_usage_errors_exit_2(run: Run) -> None:
    r = run("skill", "create")
    assert r.exit_code == 2
    r = run("reproduce", "x")
    assert r.exit_code == 2 and "--start" in r.output
    r = run("nonsense")
    assert r.exit_code == 2


@pytest.mark.parametrize(("args", "option"), [
    (["reproduce", "flat", "--start", "0,,0.04"], "--start"),
    (["reproduce", "flat", "--start", ",0,0.04"], "--start"),
    (["reproduce", "flat", "--start", "0,0.04,"], "--start"),
    (["reproduce", "flat", "--start", "0,0", "--goal", "1,,0"], "--goal"),
    (["reproduce", "flat", "--start", "0,0,0", "--start-orientation", "0,0,,1"], "--start-orientation"),
    (["reproduce", "flat", "--start", "0,0,0", "--obstacle", "sphere:0.5,,0,0.02"], "--obstacle"),
    (["scene", "set", "flat", "--obstacle", "box:0.5,0,0,0.01,0.5,0.5,"], "--obstacle"),
    (["sim", "flat", "--start", "0,,0"], "--start"),
    (["sim", "flat", "--push", "1:0,,0.05"], "--push"),
    (["sim", "flat", "--keep-out", "0.5,,0:0.02"], "--keep-out"),
])
def test_a_number_left_empty_is_a_usage_error_naming_its_option(
        run: Run, args: list[str], option: str) -> None:
    # "0,,0.04" was read as the point (0, 0.04): the empty field was dropped, and a 3-D
    # start became a 2-D one. Every option that takes numbers refuses it before any request.
    r = run(*args, url=closed_port_url())
    assert r.exit_code == 2, (args, r.output)
    assert option in r.output and "left empty" in r.output, (args, r.output)


def test_help_offers_the_contracts_choices(run: Run) -> None:
    # The choices are canal_core's and the limits the HTTP contract's, not a copy in the CLI:
    # a kind added to canal_core shows up here without touching the CLI.
    low, high = field_bounds(FitRequest, "n_samples")
    r = run("fit", "--help", url=closed_port_url())
    assert r.exit_code == 0, r.output
    for choices in (CROSS_SECTIONS, FRAMES, ALIGNMENTS, DIRECTRICES):
        assert "<" + "|".join(choices) + ">" in r.stdout
    assert f"[{low}<=x<={high}]" in r.stdout
    outside = typing.get_args(ReproductionRequest.model_fields["outside"].annotation)
    r = run("reproduce", "--help", url=closed_port_url())
    assert r.exit_code == 0 and "<" + "|".join(outside) + ">" in r.stdout
    assert "<" + "|".join(PERSISTENCES) + ">" in r.stdout
    r = run("demo", "add", "s", "--help", url=closed_port_url())
    assert r.exit_code == 0 and "--topic" in r.stdout and ".mcap" in r.stdout
    r = run("sim", "--help", url=closed_port_url())
    assert r.exit_code == 0 and "<first-order|pd>" in r.stdout and "--push" in r.stdout


def test_every_fit_choice_is_sent_and_others_are_usage_errors(run: Run) -> None:
    # Exit 3 (service unreachable) means the option was accepted and a request was tried.
    url = closed_port_url()
    low, high = field_bounds(FitRequest, "n_samples")
    for option, choices in (("--cross-section", CROSS_SECTIONS), ("--frames", FRAMES),
                            ("--alignment", ALIGNMENTS), ("--directrix", DIRECTRICES)):
        for value in choices:
            r = run("fit", "x", option, value, url=url)
            assert r.exit_code == 3, (option, value, r.output)
        r = run("fit", "x", option, "no-such-choice", url=url)
        assert r.exit_code == 2 and "no-such-choice" in r.output, (option, r.output)
        said = " ".join(r.output.replace("│", " ").split())
        assert "expected one of " + ", ".join(map(repr, choices)) in said, (option, said)
    assert run("fit", "x", "--samples", str(high), url=url).exit_code == 3
    for bad in (high + 1, low - 1):
        r = run("fit", "x", "--samples", str(bad), url=url)
        assert r.exit_code == 2 and "--samples" in r.output, r.output


def test_a_choice_not_offered_is_named_with_the_choices(run: Run) -> None:
    # typer's own check words it as a pydantic "Value error, 'x' is not one of ...".
    url = closed_port_url()
    outside = typing.get_args(ReproductionRequest.model_fields["outside"].annotation)
    for args, choices in (
        (["reproduce", "x", "--start", "0,0,0", "--outside", "bogus"], outside),
        (["reproduce", "x", "--start", "0,0,0", "--persistence", "bogus"], PERSISTENCES),
        (["correct", "x", "missing.csv", "--kind", "bogus"], ("include", "exclude")),
        (["sim", "x", "--lag", "bogus"], ("first-order", "pd")),
        (["sim", "x", "--encoding", "bogus"], ("binary", "json")),
    ):
        r = run(*args, url=url)
        said = " ".join(r.output.replace("│", " ").split())
        assert r.exit_code == 2, (args, said)
        assert "Value error" not in said, (args, said)
        assert f"expected one of {', '.join(map(repr, choices))}, got 'bogus'" in said, (args, said)


def test_a_number_option_refused_says_what_came(run: Run) -> None:
    # typer's own conversion said "Input should be a valid integer, unable to parse string
    # as an integer", naming the option but not what was typed.
    url = closed_port_url()
    for args, got in (
        (["demo", "rm", "x", "abc"], "got 'abc'"),
        (["demo", "rm", "x", "0"], "got '0'"),
        (["corrections", "undo", "x", "abc"], "got 'abc'"),
        (["fit", "x", "--demo", "two"], "got 'two'"),
        (["fit", "x", "--samples", "many"], "got 'many'"),
        (["sim", "x", "--rate", "fast"], "got 'fast'"),
    ):
        r = run(*args, url=url)
        said = " ".join(r.output.replace("│", " ").split())
        assert r.exit_code == 2, (args, said)
        assert "Invalid value for" in said and said.rstrip(".").endswith(got), (args, said)


def test_cli_runs_without_the_service_package(service: LiveService, tmp_path: Path) -> None:
    # The client must not depend on the service: with canal_service and the service's own
    # dependencies made unimportable, the CLI still talks to a service, and `canal serve`
    # names what to install instead of a traceback.
    code = f"""
import sys
for name in {SERVICE_ONLY!r}:
    sys.modules[name] = None  # import raises ModuleNotFoundError, find_spec answers None
from typer.testing import CliRunner
from canal_client.cli import app
r = CliRunner().invoke(app, ["--url", {service.url!r}, "--json", "skill", "list"])
assert r.exit_code == 0, r.output
assert isinstance(__import__("json").loads(r.stdout), list)
assert CliRunner().invoke(app, ["fit", "--help"]).exit_code == 0
r = CliRunner().invoke(app, ["serve", "--port", "1"])
print(r.exit_code)
print(r.stderr)
loaded = sorted(m for m in {SERVICE_ONLY!r} if sys.modules.get(m) is not None)
print("loaded:", loaded)
"""
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=120, env={**os.environ, "CANAL_TOKEN": ""})
    assert p.returncode == 0, p.stderr[-3000:]
    exit_code, *rest = p.stdout.splitlines()
    assert exit_code == "1", p.stdout
    assert "error: canal serve runs the Canal service, but the canal_service package is not " \
           "installed" in p.stdout
    assert SERVICE_INSTALL in p.stdout and "loaded: []" in rest


def test_sim_drives_a_robot_to_the_end(unique_name: Callable[[str], str], tmp_path: Path) -> None:
    from canal_client.cli import app
    from typer.testing import CliRunner

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with LiveService(tmp_path / "data", zenoh_enabled=True, zenoh_listen=[endpoint]) as live:
        name = unique_name("sim")
        make_fitted(live, name)
        env = {"CANAL_URL": live.url, "CANAL_TOKEN": ""}
        r = CliRunner().invoke(app, ["--json", "sim", name, "--endpoint", endpoint,
                                     "--start", "0,0.01,0", "--rate", "50", "--timeout", "30",
                                     "--push", "0.2:0,0.01,0"], env=env)
        assert r.exit_code == 0, r.output
        result = json.loads(r.stdout)
        assert result["reached_end"] is True and result["all_inside"] is True
        assert result["n_steps"] > 0 and result["min_eta"] <= result["max_eta"]
        (push,) = result["pushes"]
        assert push["offset"] == [0.0, 0.01, 0.0] and push["at_s"] >= 0.2
        # the normal output says what each push did, and which never happened
        r = CliRunner().invoke(app, ["sim", name, "--endpoint", endpoint, "--start", "0,0.01,0",
                                     "--rate", "50", "--timeout", "30", "--push", "0.2:0,0.01,0",
                                     "--push", "99:0,0.01,0"], env=env)
        assert "push (0,0.01,0) applied at " in r.stdout, r.output
        assert "push 99 s:0,0.01,0 not applied: the run ended" in r.stdout, r.output
        r = CliRunner().invoke(app, ["sim", name, "--endpoint", endpoint, "--push", "x"],
                               env=env)
        assert r.exit_code == 2 and "--push" in r.output
        # Each of these ran before: a 2-D point on a 3-D skill ended in numpy's "operands
        # could not be broadcast" or in a run of unanswered poses; a gain of 0, -1 or nan
        # stood still or drove the robot away; a timeout of 0 reported "left the canal".
        for flags, option, said in (
            (["--start", "0,0.01"], "--start", "3 coordinates"),
            (["--push", "0.2:0,0.01"], "--push", "3 coordinates"),
            (["--keep-out", "0.5,0:0.02"], "--keep-out", "3 coordinates"),
            (["--gain", "0"], "--gain", "> 0"),
            (["--gain", "-1"], "--gain", "> 0"),
            (["--gain", "nan"], "--gain", "> 0"),
            (["--timeout", "0"], "--timeout", "> 0"),
            (["--timeout", "inf"], "--timeout", "> 0"),
        ):
            r = CliRunner().invoke(app, ["sim", name, "--endpoint", endpoint, "--timeout", "5",
                                         *flags], env=env)
            assert r.exit_code == 2, (flags, r.output)
            assert option in r.output and said in r.output, (flags, r.output)
            assert "broadcast" not in r.output and "steps in" not in r.output, (flags, r.output)


def test_sim_without_the_services_token_says_so(unique_name: Callable[[str], str],
                                               tmp_path: Path) -> None:
    # The bridge refuses a session without the token (or with another): that was "no Canal
    # bridge subscribes to canal/SKILL/sim/pose", as if there were none.
    from canal_client.cli import app
    from typer.testing import CliRunner

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with LiveService(tmp_path / "data", zenoh_enabled=True, zenoh_listen=[endpoint],
                     zenoh_processes=0, token="s3cret") as live:
        name = unique_name("sim-token")
        with CanalClient(live.url, token="s3cret") as c:
            c.create_skill(name)
            for j in range(4):
                c.add_demo(name, demo_positions(j))
            c.fit(name, n_samples=30)
        for token, said in (("", "the service's live path admits only sessions that give its "
                                 "token: pass it with --token (CANAL_TOKEN)"),
                            ("wrong", "the service refused the token given (--token): missing "
                                      "or wrong bearer token")):
            r = CliRunner().invoke(app, ["sim", name, "--timeout", "1"],
                                   env={"CANAL_URL": live.url, "CANAL_TOKEN": token})
            assert r.exit_code == 1, r.output
            assert said in " ".join(r.stderr.split()), r.stderr
        r = CliRunner().invoke(app, ["--json", "sim", name, "--start", "0,0.01,0", "--timeout",
                                     "30"], env={"CANAL_URL": live.url, "CANAL_TOKEN": "s3cret"})
        assert r.exit_code == 0, r.output


def test_view_opens_the_viewer_when_there_is_a_display(
        run: Run, service: LiveService, unique_name: Callable[[str], str],
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    from canal_client.cli import recordings

    name = unique_name("view")
    make_fitted(service, name)
    spawned: list[list[str]] = []
    monkeypatch.setattr(recordings, "spawn_detached", spawned.append)
    monkeypatch.setattr(recordings, "rerun_command", lambda: ["/opt/rerun"])
    r = run("view", name, env={"DISPLAY": ":0"})
    assert r.exit_code == 0, r.output
    cached = tmp_path / "cache" / f"{name}.rrd"
    assert spawned == [["/opt/rerun", str(cached)]] and "opened" in r.stdout
    r = run("view", name, "--no-open", env={"DISPLAY": ":0"})
    assert len(spawned) == 1 and f"open it with: /opt/rerun {cached}" in r.stdout
    monkeypatch.setattr(recordings, "rerun_command", lambda: None)
    r = run("view", name, env={"DISPLAY": ":0"})
    assert len(spawned) == 1 and "pip install rerun-sdk" in r.stdout
    assert f"open it with: rerun {cached}" in r.stdout


def test_a_url_without_a_scheme_is_http(run: Run, service: LiveService) -> None:
    # `--url localhost:8000`, as curl takes it, was "unsupported protocol 'localhost://'".
    bare = service.url.removeprefix("http://")
    r = run("--json", "skill", "list", url=bare)
    assert r.exit_code == 0, r.output
    assert isinstance(json.loads(r.stdout), list)
    r = run("skill", "list", url="ftp://" + bare)
    assert r.exit_code == 2 and "expected an http:// or https:// URL" in r.output, r.output


def test_a_url_that_names_no_service_is_a_usage_error(run: Run) -> None:
    # 'http://[::1' was an httpx.InvalidURL traceback; '' (and one without a host) was exit 3
    # "cannot reach the Canal service at http:".
    for bad in ("http://[::1", "", "  ", "http://", "http://:8000", "http://127.0.0.1:99999",
                "127.0.0.1:port"):
        tries = [run("--url", bad, "skill", "create", "u-bad")]
        if bad:  # an empty CANAL_URL is no CANAL_URL (the default URL)
            tries.append(run("skill", "create", "u-bad", url=bad))
        for r in tries:
            said = " ".join(r.output.replace("│", " ").split())
            assert r.exit_code == 2, (bad, r.output)
            assert "--url (or CANAL_URL)" in said and f"got {bad.strip()!r}" in said, (bad, said)
            assert "Traceback" not in r.output and "cannot reach" not in r.output, (bad, said)
    assert run("skill", "show", "u-bad").exit_code == 1  # nothing was created


def test_sim_with_a_zenoh_option_that_cannot_be_used_says_which(
        run: Run, service: LiveService, unique_name: Callable[[str], str],
        tmp_path: Path) -> None:
    # Each was a zenoh.ZError traceback; the scene asked for with --obstacle must stay unset.
    name = unique_name("sim-zenoh")
    make_fitted(service, name)
    malformed = tmp_path / "bad.json5"
    malformed.write_text('{ mode: "peer", ')
    missing = tmp_path / "missing.json5"
    for flags, option, said in (
        (["--endpoint", "garbage"], "--endpoint", "got 'garbage'"),
        (["--endpoint", "tcp/127.0.0.1:7447,tcp/"], "--endpoint", "got 'tcp/'"),
        (["--endpoint", ""], "--endpoint", "got ''"),
        (["--zenoh-config", str(missing)], "--zenoh-config",
         f"got {str(missing)!r}, which does not exist"),
        (["--zenoh-config", str(tmp_path)], "--zenoh-config",
         f"got {str(tmp_path)!r}, which is not a file"),
        (["--zenoh-config", str(malformed)], "--zenoh-config",
         f"got {str(malformed)!r}: line 1, column 17: expected identifier or string"),
    ):
        r = run("sim", name, *flags, "--obstacle", "sphere:0.5,0,0,0.05", "--timeout", "1")
        said_all = " ".join(r.output.replace("│", " ").split())
        assert r.exit_code == 2, (flags, r.output)
        assert f"Invalid value for {option}" in said_all and said in said_all, (flags, said_all)
        assert "Traceback" not in r.output and ".rs:" not in r.output, (flags, r.output)
    with CanalClient(service.url) as c:
        assert c.get_scene(name).obstacles == []


def test_sim_that_cannot_connect_through_its_config_is_a_runtime_failure(
        run: Run, unique_name: Callable[[str], str], tmp_path: Path) -> None:
    # A client-mode config whose router does not answer: zenoh.open's ZError was a traceback.
    config = tmp_path / "client.json5"
    config.write_text(json.dumps({"mode": "client",
                                  "connect": {"endpoints": [f"tcp/127.0.0.1:{free_port()}"]},
                                  "scouting": {"multicast": {"enabled": False}}}))
    r = run("sim", unique_name("sim-noroute"), "--zenoh-config", str(config), "--prefix",
            "canal", "--timeout", "1")
    assert r.exit_code == 1, r.output
    assert r.stderr.startswith("error: simulation failed: cannot open a Zenoh session"), r.stderr
    assert "Traceback" not in r.output and ".rs:" not in r.output, r.output


def test_sim_says_the_wait_it_used_and_that_a_robot_needs_a_name(run: Run) -> None:
    # --timeout 1 said "(waited 5.0 s)"; --robot '' was "expected robot without '/', ...".
    flags = ["--endpoint", f"tcp/127.0.0.1:{free_port()}", "--prefix", "canal"]
    r = run("sim", "nobody-listens", *flags, "--timeout", "1", url=closed_port_url())
    assert r.exit_code == 1, r.output
    assert "no Canal bridge subscribes to canal/nobody-listens/sim/pose (waited 1 s)" in r.stderr
    for robot, said in (("", "expected robot that is not empty, got ''"),
                        ("arm/1", "expected robot without '/', '*', '$', '?' or '#', "
                                  "got 'arm/1'")):
        r = run("sim", "x", *flags, "--robot", robot, url=closed_port_url())
        said_all = " ".join(r.output.replace("│", " ").split())
        assert r.exit_code == 2, (robot, r.output)
        assert f"Invalid value for --robot: {said}" in said_all, (robot, said_all)
    # a prefix with a wildcard published on every skill's keys it matches; a push a
    # thousand light years long made every later pose a bad_payload
    for args, flag, said in ((["--prefix", "x/*"], "--prefix", "'*'"),
                             (["--prefix", "a//b"], "--prefix", "empty"),
                             (["--push", "0.3:1e300,0,0"], "--push", "1e+15")):
        r = run("sim", "x", "--endpoint", f"tcp/127.0.0.1:{free_port()}", *args,
                url=closed_port_url())
        said_all = " ".join(r.output.replace("│", " ").split())
        assert r.exit_code == 2 and flag in said_all and said in said_all, (args, said_all)


def test_recordings_rebuild_counts_the_reproductions_it_logs(
        run: Run, service: LiveService, unique_name: Callable[[str], str]) -> None:
    # The help said reproductions "are not stored, so they are not kept", and the summary
    # left them out, while the service rebuilds the ones its database keeps.
    name = unique_name("rebuild")
    make_fitted(service, name)
    with CanalClient(service.url) as c:
        c.reproduce(name, [0.0, 0.01, 0.0])
        c.reproduce(name, [0.0, 0.02, 0.0])
    r = run("--json", "recordings", "rebuild", name)
    assert r.exit_code == 0, r.output
    body = json.loads(r.stdout)
    assert (body["demos"], body["models"], body["reproductions"]) == (4, 1, 2), body
    r = run("recordings", "rebuild", name)
    assert r.exit_code == 0, r.output
    assert (f"rebuilt the recordings of {name}: 4 demonstrations, 1 model versions, "
            "2 reproductions") in r.stdout
    r = run("recordings", "rebuild", "--help")
    said = " ".join(r.stdout.split())
    assert r.exit_code == 0 and "the reproductions it keeps" in said, said
    assert "reproductions are not stored" not in said, said


#: Values the CLI can judge itself, against the contract's limits (canal_protocol): each is a
#: usage error naming the option, what it expects and what came, before any request.
_LONG = "x" * (MAX_CORRECTION_LABEL + 100)
_REFUSED_HERE: list[tuple[list[str], str, str, str]] = [
    (["fit", "x", "--route-separation", "0"], "--route-separation", "a number in [0.01, 4]", "got '0'"),
    (["fit", "x", "--route-separation", "-1"], "--route-separation", "a number in [0.01, 4]", "got '-1'"),
    (["fit", "x", "--route-separation", "nan"], "--route-separation", "a number in [0.01, 4]", "got 'nan'"),
    (["fit", "x", "--route-separation", "inf"], "--route-separation", "a number in [0.01, 4]", "got 'inf'"),
    (["fit", "x", "--route-separation", "0.001"], "--route-separation", "a number in [0.01, 4]",
     "got '0.001'"),
    (["fit", "x", "--frame-smoothing", "nan"], "--frame-smoothing", "a number in [0, ", "got 'nan'"),
    (["fit", "x", "--demo", "1", "--demo", "0"], "--demo", f"a whole number in [1, {MAX_ID}]", "got '0'"),
    (["reproduce", "x", "--start", "0,0,0", "--model", "0"], "--model",
     f"'latest' or a model version in [1, {MAX_ID}]", "got '0'"),
    (["reproduce", "x", "--start", "0,0,0", "--model", "-3"], "--model",
     f"'latest' or a model version in [1, {MAX_ID}]", "got '-3'"),
    (["correct", "x", "FILE", "--model", "0"], "--model", "'latest' or a model version", "got '0'"),
    (["correct", "x", "FILE", "--weight", "nan"], "--weight", "a number in (0, 1000]", "got 'nan'"),
    (["correct", "x", "FILE", "--label", _LONG], "--label",
     f"text of at most {MAX_CORRECTION_LABEL} characters", f"got {len(_LONG)} characters"),
    (["demo", "add", "x", "FILE", "--label", "y" * (MAX_DEMO_LABEL + 1)], "--label",
     f"text of at most {MAX_DEMO_LABEL} characters", f"got {MAX_DEMO_LABEL + 1} characters"),
    (["skill", "create", "x", "--description", "d" * 4001], "--description",
     "text of at most 4000 characters", "got 4001 characters"),
    (["corrections", "undo", "x", "0"], "'id'", f"a whole number in [1, {MAX_ID}]", "got '0'"),
    (["corrections", "undo", "x", "-1"], "'id'", f"a whole number in [1, {MAX_ID}]", "got '-1'"),
    (["corrections", "undo", "x", "--", "-1"], "'id'", f"a whole number in [1, {MAX_ID}]", "got '-1'"),
    (["demo", "rm", "x", "1", "-2"], "'ids'", f"a whole number in [1, {MAX_ID}]", "got '-2'"),
    (["demo", "rm", "x", "0"], "'ids'", f"a whole number in [1, {MAX_ID}]", "got '0'"),
    (["demo", "add", "x", "FILE", "--time-unit", "hours"], "--time-unit",
     "one of 's', 'ms', 'us', 'ns'", "got 'hours'"),
    (["demo", "add", "x", "FOLDER", "--time-unit", "hours"], "--time-unit",
     "one of 's', 'ms', 'us', 'ns'", "got 'hours'"),
    (["demo", "add", "x", "FILE", "--format", "xls"], "--format",
     "one of 'csv', 'npy', 'mcap', 'json'", "got 'xls'"),
    (["correct", "x", "FILE", "--time-unit", "hours"], "--time-unit",
     "one of 's', 'ms', 'us', 'ns'", "got 'hours'"),
]


@pytest.mark.parametrize(("args", "option", "expected", "got"), _REFUSED_HERE,
                         ids=[" ".join(a[:4])[:60] for a, *_ in _REFUSED_HERE])
def test_a_value_the_contract_refuses_is_a_usage_error_naming_its_option(
        run: Run, tmp_path: Path, args: list[str], option: str, expected: str, got: str) -> None:
    # These were sent, and came back as the service's 422 naming the request field (exit 1):
    # `--route-separation 0`, `--demo 0`, `--model 0`, a label too long, `corrections undo
    # SKILL 0`, `--time-unit hours`, `--format xls`; a negative id was "No such option: -1".
    file = write_demo_files(tmp_path)["csv"]
    args = [{"FILE": str(file), "FOLDER": str(file.parent)}.get(a, a) for a in args]
    r = run(*args, url=closed_port_url())
    said = " ".join(r.output.replace("│", " ").split())
    assert r.exit_code == 2, (args, said)
    assert f"Invalid value for {option}" in said or f"Invalid value for '{option}'" in said, said
    assert f"expected {expected}" in said and got in said, (args, said)


def test_values_within_the_contracts_limits_are_sent(run: Run, tmp_path: Path) -> None:
    # exit 3: the option was accepted and a request was tried
    file = str(write_demo_files(tmp_path)["csv"])
    url = closed_port_url()
    low, high = field_bounds(FitRequest, "route_separation")
    for args in (["fit", "x", "--route-separation", str(high)], ["fit", "x", "--route-separation", "0.01"],
                 ["fit", "x", "--demo", "1", "--demo", str(MAX_ID)],
                 ["reproduce", "x", "--start", "0,0,0", "--model", "1"],
                 ["reproduce", "x", "--start", "0,0,0", "--model", "latest"],
                 ["correct", "x", file, "--label", "l" * MAX_CORRECTION_LABEL, "--model", "2"],
                 ["demo", "add", "x", file, "--label", "l" * MAX_DEMO_LABEL],
                 ["demo", "add", "x", file, "--time-unit", "ms", "--format", "CSV"],
                 ["correct", "x", file, "--time-unit", "ns"],
                 ["skill", "create", "x", "--description", "d" * 4000],
                 ["corrections", "undo", "x", "1"], ["demo", "rm", "x", "1", "2"]):
        r = run(*args, url=url)
        assert r.exit_code == 3, (args, r.output)
    r = run("corrections", "undo", "x", "1", "--bogus", url=url)
    assert r.exit_code == 2 and "No such option: --bogus" in r.output, r.output


def test_a_missing_file_is_a_usage_error_naming_it(run: Run, tmp_path: Path) -> None:
    # `demo add` reported it per file (exit 1) while `correct` refused it as usage (exit 2).
    good = str(write_demo_files(tmp_path)["csv"])
    missing = tmp_path / "missing.csv"
    for args in (["demo", "add", "x", good, str(missing)], ["demo", "add", "x", str(tmp_path / "gone")],
                 ["correct", "x", str(missing)]):
        r = run(*args, url=closed_port_url())  # exit 2, not 3: nothing was sent
        said = " ".join(r.output.replace("│", " ").split())
        assert r.exit_code == 2, (args, said)
        assert "Invalid value for" in said and f"no file {args[-1]!r}" in said, said


def test_an_empty_skill_name_is_named_in_the_error(run: Run) -> None:
    # `canal skill show ''` printed "error: HTTP 307".
    demo = Path(__file__).resolve().parents[2] / "examples" / "demos" / "demo_1.csv"
    for args in (("skill", "show", ""), ("demo", "add", "", str(demo)),
                 ("fit", ""), ("skill", "delete", "", "--yes")):
        r = run(*args)
        assert r.exit_code == 1 and r.stderr.startswith("error: skill: expected a skill name"), (
            args, r.output)
