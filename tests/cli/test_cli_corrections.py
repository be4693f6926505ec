"""``canal correct`` and ``canal corrections list|undo`` against a real service."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from canal_client import CanalClient
from canal_live import LiveService, demo_positions
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



def test_a_reproduction_file_is_a_correction_path(tmp_path: Path) -> None:
    """`canal reproduce --out x.csv` writes t,x,y,z (and qx..qw): `canal correct` reads x,y,z."""
    from canal_client.cli.corrections import read_path

    path = tmp_path / "traj.csv"
    path.write_text("t,x,y,z,qx,qy,qz,qw\n0,1,2,3,0,0,0,1\n0.5,4,5,6,0,0,0,1\n")
    np.testing.assert_array_equal(read_path(path, 3), [[1, 2, 3], [4, 5, 6]])
    path.write_text("1,2,3\n4,5,6\n")  # no header: the numbers are the samples
    np.testing.assert_array_equal(read_path(path, 3), [[1, 2, 3], [4, 5, 6]])


def test_numpys_savetxt_file_is_a_correction_path(tmp_path: Path) -> None:
    # np.savetxt(..., header="t,x,y,z") writes "# t,x,y,z": the '#' hid the names, so the
    # columns were taken as they came and t, x, y became the samples' x, y, z.
    from canal_client.cli.corrections import read_path

    t = np.array([0.0, 0.5, 1.0])
    xyz = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]])
    path = tmp_path / "push.csv"
    np.savetxt(path, np.column_stack([t, xyz]), delimiter=",", header="t,x,y,z")
    np.testing.assert_array_equal(read_path(path, 3), xyz)
    path.write_text("# pushed by hand\n# rate 100 Hz\nx,y,z\n1,2,3\n4,5,6\n7,8,9\n")
    np.testing.assert_array_equal(read_path(path, 3), xyz)
    path.write_text("# pushed by hand\n1,2,3\n4,5,6\n7,8,9\n")
    np.testing.assert_array_equal(read_path(path, 3), xyz)


@pytest.mark.parametrize("encoding", ["utf-8-sig", "utf-16"])
def test_a_spreadsheet_export_with_a_byte_order_mark_is_a_correction_path(tmp_path: Path, encoding: str) -> None:
    # With a UTF-8 mark the first name read "\ufeffx" and the t column became x; UTF-16 was
    # not read at all. The service reads both as uploads.
    from canal_client.cli.corrections import read_path

    path = tmp_path / "push.csv"
    path.write_bytes("t,x,y,z\r\n0,1,2,3\r\n0.5,4,5,6\r\n".encode(encoding))
    np.testing.assert_array_equal(read_path(path, 3), [[1, 2, 3], [4, 5, 6]])


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
    # log, a PlotJuggler export or a semicolon file `canal demo add` takes was refused.
    name = unique_name("dialects")
    run("skill", "create", name)
    xyz = demo_positions(0)[:30]
    for file_name, data in _dialects(xyz).items():
        path = tmp_path / file_name
        path.write_bytes(data)
        r = run("--json", "demo", "add", name, str(path))
        assert r.exit_code == 0, (file_name, r.output)
    with CanalClient(service.url) as client:
        stored = [client.get_demo(name, d.id).positions for d in client.list_demos(name)]
    assert len(stored) == len(_dialects(xyz))
    from canal_client.cli.corrections import read_path

    for (file_name, _), positions in zip(_dialects(xyz).items(), stored, strict=True):
        np.testing.assert_allclose(read_path(tmp_path / file_name, 3), positions, err_msg=file_name)
    bad = tmp_path / "bad.csv"
    bad.write_text("x,y,z\n1,2,3\n4,oops,6\n")
    r = run("correct", name, str(bad))
    assert r.exit_code == 2 and "expected numbers on CSV line 3, got 'oops'" in r.output, r.output
