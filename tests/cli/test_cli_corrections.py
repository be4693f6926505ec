"""``canal correct`` and ``canal corrections list|undo`` against a real service."""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
from canal_client import CanalClient
from canal_live import LiveService, demo_positions, foxglove_pose_mcap
from click.testing import Result

import canal_core

Run = Callable[..., Result]


def test_correct_list_and_undo(run: Run, service: LiveService, unique_name: Callable[[str], str],
                               tmp_path: Path) -> None:
    name = unique_name("correct")
    run("skill", "create", name)
    for j in range(4):
        np.save(tmp_path / f"d{j}.npy", demo_positions(j))
    assert run("demo", "add", name, str(tmp_path)).exit_code == 0
    assert run("fit", name, "--samples", "60").exit_code == 0
    with CanalClient(service.url) as client:
        canal: canal_core.Canal = client.get_canal(name)
    idx = np.arange(20, 36)
    wider = canal.directrix[idx] + 1.5 * canal.radii[idx, None] * canal.normals[idx]
    path = tmp_path / "wider.csv"
    np.savetxt(path, wider, delimiter=",", header="x,y,z", comments="")
    r = run("correct", name, str(path), "--kind", "include", "--label", "wider here")
    assert r.exit_code == 0, r.output
    assert "model version 2 (parent 1)" in r.stdout
    rows = json.loads(run("--json", "corrections", "list", name).stdout)
    assert [(c["kind"], c["label"], c["undone"]) for c in rows] == [("include", "wider here", False)]
    r = run("fit", name, "--samples", "60")
    assert r.exit_code == 0 and "re-applied (version 4, parent 3)" in r.stdout, r.output
    r = run("corrections", "undo", name, str(rows[0]["id"]))
    assert r.exit_code == 0 and "model version 5" in r.stdout, r.output
    r = run("corrections", "undo", name, str(rows[0]["id"]))
    assert r.exit_code == 1 and "not part of the latest" in r.stderr
    r = run("--json", "fit", name, "--samples", "60", "--drop-corrections")
    assert r.exit_code == 0 and json.loads(r.stdout)["corrections"] == [], r.output
    far = tmp_path / "far.npy"
    np.save(far, wider + 10.0)
    r = run("correct", name, str(far), "--kind", "exclude")
    assert r.exit_code == 1 and "outside every section" in r.stderr
    assert run("correct", name, str(tmp_path / "missing.csv")).exit_code == 2
    for weight in ("0", "5000", "nan"):
        r = run("correct", name, str(path), "--weight", weight)
        assert r.exit_code == 2 and "(0, 1000]" in r.output, r.output
    # a logger's nanoseconds, said with --time-unit as for a demonstration
    stamped = tmp_path / "stamped.csv"
    t_ns = np.arange(len(wider)) * 8_000_000
    np.savetxt(stamped, np.column_stack([t_ns, wider]), delimiter=",", header="t,x,y,z",
               comments="", fmt=["%d", "%.17g", "%.17g", "%.17g"])
    r = run("correct", name, str(stamped))
    assert r.exit_code == 1 and "time_unit" in r.stderr, r.output
    r = run("correct", name, str(stamped), "--time-unit", "ns")
    assert r.exit_code == 0, r.output



def _dialects(xyz: np.ndarray) -> dict[str, bytes]:
    """The same samples as the loggers people record with write them."""
    t = np.arange(len(xyz)) * 0.01
    rows = lambda sep, cols: "\n".join(sep.join(f"{v:.6f}" for v in r) for r in cols) + "\n"  # noqa: E731
    rot = np.zeros_like(xyz)
    return {
        "semicolon.csv": ("t;x;y;z\n" + rows(";", np.column_stack([t, xyz]))).encode(),
        "rtde.csv": ("timestamp " + " ".join(f"actual_TCP_pose_{k}" for k in range(6)) + "\n"
                     + rows(" ", np.column_stack([t, xyz, rot]))).encode(),
        "plotjuggler.csv": ("__time,/ee_pose/pose/position/x,/ee_pose/pose/position/y,"
                            "/ee_pose/pose/position/z\n"
                            + rows(",", np.column_stack([t, xyz]))).encode(),
        "utf16.csv": ("x,y,z\n" + rows(",", xyz)).encode("utf-16"),
        "tabs.txt": ("time\tx\ty\tz\n" + rows("\t", np.column_stack([t, xyz]))).encode(),
    }


def test_every_file_a_demonstration_is_read_from_is_read_as_a_correction_too(
        run: Run, service: LiveService, unique_name: Callable[[str], str], tmp_path: Path) -> None:
    # `canal correct` had a CSV reader of its own: commas and x, y, z names only, so an RTDE
    # log, a PlotJuggler export or a semicolon file `canal demo add` takes was refused, and a
    # ROS 2 bag could not be a correction at all.
    name = unique_name("dialects")
    run("skill", "create", name)
    for j in range(4):
        np.save(tmp_path / f"d{j}.npy", demo_positions(j))
    assert run("demo", "add", name, *(str(tmp_path / f"d{j}.npy") for j in range(4))).exit_code == 0
    assert run("fit", name, "--samples", "60").exit_code == 0
    with CanalClient(service.url) as client:
        canal: canal_core.Canal = client.get_canal(name)
    idx = np.arange(20, 36)
    wider = canal.directrix[idx] + 1.2 * canal.radii[idx, None] * canal.normals[idx]
    files = _dialects(wider)
    (tmp_path / "pushed.mcap").write_bytes(foxglove_pose_mcap(wider))
    for file_name in [*files, "pushed.mcap"]:
        path = tmp_path / file_name
        if file_name in files:
            path.write_bytes(files[file_name])
        r = run("--json", "correct", name, str(path))
        assert r.exit_code == 0, (file_name, r.output)
        made = json.loads(r.stdout)["correction"]
        assert made["n_points"] == len(wider) and made["label"] == file_name, (file_name, made)
    bad = tmp_path / "bad.csv"
    bad.write_text("x,y,z\n1,2,3\n4,oops,6\n")
    r = run("correct", name, str(bad))
    assert r.exit_code == 1 and "expected numbers on CSV line 3, got 'oops'" in r.stderr, r.output
    # A demonstration's own JSON file ({"positions": ...}) is a path too.
    demo_json = tmp_path / "demo.json"
    demo_json.write_text(json.dumps({"positions": wider.tolist()}))
    r = run("--json", "correct", name, str(demo_json))
    assert r.exit_code == 0 and json.loads(r.stdout)["correction"]["n_points"] == len(wider), r.output
    r = run("correct", name, str(tmp_path / "pushed.xls"))
    said = " ".join(r.output.replace("\u2502", " ").split())
    assert r.exit_code == 2 and "expected a .csv, .npy, .mcap or .json file, got 'pushed.xls'" in said, said
    assert "format=" not in said, said  # the command has no such option


def test_a_folder_or_a_device_is_not_a_file_to_read(run: Run, tmp_path: Path) -> None:
    # A folder named like a CSV ended `canal correct` in a traceback (IsADirectoryError),
    # `canal demo add` called /dev/null "no such file" and `canal scene set` of a named pipe
    # waited for ever.
    (tmp_path / "pushed.csv").mkdir()
    r = run("correct", "any", str(tmp_path / "pushed.csv"), "--kind", "include")
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert "expected a file, got the folder" in r.output, r.output
    os.mkfifo(tmp_path / "piped.csv")
    r = run("correct", "any", str(tmp_path / "piped.csv"), "--kind", "include")
    assert r.exit_code == 2 and "expected a regular file" in r.output, r.output
    r = run("demo", "add", "any", "/dev/null")
    assert r.exit_code == 2 and "expected a regular file" in r.output, r.output
    r = run("scene", "set", "any", str(tmp_path / "piped.csv"))  # waited for a writer
    assert r.exit_code == 2 and "expected a regular file" in r.output, r.output
