"""The one CSV reader (demonstration uploads and corrections): the files people make."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from canal_protocol.codecs.csv_table import InvalidCsv, csv_table


def _read(path: Path) -> np.ndarray:
    return csv_table(path.read_bytes(), 3).positions


def test_a_reproduction_file_is_a_correction_path(tmp_path: Path) -> None:
    """`canal reproduce --out x.csv` writes t,x,y,z (and qx..qw): the samples are x,y,z."""
    path = tmp_path / "traj.csv"
    path.write_text("t,x,y,z,qx,qy,qz,qw\n0,1,2,3,0,0,0,1\n0.5,4,5,6,0,0,0,1\n")
    np.testing.assert_array_equal(_read(path), [[1, 2, 3], [4, 5, 6]])
    path.write_text("1,2,3\n4,5,6\n")  # no header: the numbers are the samples
    np.testing.assert_array_equal(_read(path), [[1, 2, 3], [4, 5, 6]])


def test_numpys_savetxt_file_is_a_correction_path(tmp_path: Path) -> None:
    # np.savetxt(..., header="t,x,y,z") writes "# t,x,y,z": the '#' hid the names, so the
    # columns were taken as they came and t, x, y became the samples' x, y, z.
    t = np.array([0.0, 0.5, 1.0])
    xyz = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]])
    path = tmp_path / "push.csv"
    np.savetxt(path, np.column_stack([t, xyz]), delimiter=",", header="t,x,y,z")
    np.testing.assert_array_equal(_read(path), xyz)
    path.write_text("# pushed by hand\n# rate 100 Hz\nx,y,z\n1,2,3\n4,5,6\n7,8,9\n")
    np.testing.assert_array_equal(_read(path), xyz)
    path.write_text("# pushed by hand\n1,2,3\n4,5,6\n7,8,9\n")
    np.testing.assert_array_equal(_read(path), xyz)


@pytest.mark.parametrize("encoding", ["utf-8-sig", "utf-16"])
def test_a_spreadsheet_export_with_a_byte_order_mark_is_a_correction_path(tmp_path: Path, encoding: str) -> None:
    # With a UTF-8 mark the first name read "\ufeffx" and the t column became x; UTF-16 was
    # not read at all. The service reads both as uploads.
    path = tmp_path / "push.csv"
    path.write_bytes("t,x,y,z\r\n0,1,2,3\r\n0.5,4,5,6\r\n".encode(encoding))
    np.testing.assert_array_equal(_read(path), [[1, 2, 3], [4, 5, 6]])


@pytest.mark.parametrize("cell", ["1_000", "١٢٣", "0x1p0", "1,5"])
def test_a_cell_numpy_cannot_read_is_named_with_its_line(cell: str) -> None:
    # Python's float() reads "1_000" and Arabic-Indic digits, numpy's reader does not: the
    # refusal said only "unreadable CSV rows", naming neither the line nor the cell.
    data = f"x;y;z\n0;0;0\n1;2;3\n{cell};3;4\n".encode()
    with pytest.raises(InvalidCsv) as caught:
        csv_table(data, 3)
    assert caught.value.field == "file:line 4"
    assert str(caught.value) == f"expected numbers on CSV line 4, got {cell!r}"
