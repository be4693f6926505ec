"""Rerun's native chunk call for live rows, behind one adapter.

``rr.send_columns(entity, indexes, columns=rr.Points3D.columns(...))`` spends most of its
time in Python (validating and converting each archetype field) for the ~100 rows a stream
has per flush. The live entities are always the same few components, so their Arrow columns
are built here straight from the numpy columns (the component descriptors and Arrow types
are the ones the archetypes report, learned once; the arrays equal what
``Archetype.columns`` builds, tested) and sent with the native call ``send_columns`` ends
in, ``rerun_bindings.send_arrow_chunk``, which rerun does not document. So that path is
taken only with the rerun-sdk versions it was written against (:data:`TESTED`); otherwise,
or with ``fast=False``, the rows go through the public ``rr.send_columns``.
:func:`status` says which path runs (``/healthz``).
"""

from __future__ import annotations

import functools
import importlib
import importlib.util
from importlib.metadata import version
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa  # type: ignore[import-untyped]  # rerun-sdk requires it; untyped
import rerun as rr

if TYPE_CHECKING:
    from ..recording.events import LiveRows

#: rerun-sdk versions (prefixes) the native path was written and tested against.
TESTED = ("0.41.",)
INSTALLED = version("rerun-sdk")
POSE_COLOR = (220, 40, 160, 255)
TARGET_COLOR = (40, 200, 220, 255)

# The native module: gone or changed in a future rerun-sdk means the public path (looked up,
# not imported blindly).
_send_arrow_chunk: Any = None
if importlib.util.find_spec("rerun_bindings") is not None:
    _send_arrow_chunk = getattr(importlib.import_module("rerun_bindings"), "send_arrow_chunk",
                                None)


def native_path() -> bool:
    """Whether live rows take the native chunk call with the installed rerun-sdk."""
    return _send_arrow_chunk is not None and INSTALLED.startswith(TESTED)


@functools.cache
def _components(archetype: str) -> dict[str, tuple[Any, pa.DataType]]:
    """``{field: (component descriptor, Arrow type of one value)}`` of a live archetype."""
    one3, color = np.zeros((1, 3)), np.array([[0, 0, 0, 255]])
    fields = {
        "Points3D": {"positions": one3, "colors": color},
        "Points2D": {"positions": one3[:, :2], "colors": color},
        "Transform3D": {"translation": one3, "quaternion": np.array([[0.0, 0.0, 0.0, 1.0]])},
        "Scalars": {"scalars": np.zeros(1)},
    }[archetype]
    out = {}
    for name, value in fields.items():
        # One field at a time: the one column it gives is that field's, whatever its name.
        (column,) = getattr(rr, archetype).columns(**{name: value})
        out[name] = (column.component_descriptor(), column.component_batch.as_arrow_array().type)
    return out


def _packed(rgba: tuple[int, int, int, int]) -> int:
    """An RGBA colour as Rerun's Rgba32 (0xRRGGBBAA)."""
    r, g, b, a = rgba
    return (r << 24) | (g << 16) | (b << 8) | a


def _values(values: np.ndarray, value_type: pa.DataType) -> pa.Array:
    if pa.types.is_fixed_size_list(value_type):
        with np.errstate(over="ignore"):  # a 1e308 pose is inf in float32, as rerun casts it
            flat = np.ascontiguousarray(values, dtype=np.float32).ravel()
        return pa.FixedSizeListArray.from_arrays(
            pa.array(flat, type=value_type.value_type), type=value_type)
    return pa.array(np.ascontiguousarray(values), type=value_type)


def _chunk(archetype: str, offsets: pa.Array, **fields: np.ndarray) -> dict[Any, pa.Array]:
    """One row per value (unit-length lists), as ``Archetype.columns`` partitions them."""
    spec = _components(archetype)
    return {spec[name][0]: pa.ListArray.from_arrays(offsets, _values(values, spec[name][1]))
            for name, values in fields.items()}


def live_chunks(base: str, rows: LiveRows, dim: int = 3
                ) -> list[tuple[str, dict[str, pa.Array], dict[Any, pa.Array]]]:
    """The live entities of one stream's rows as ``(entity, timelines, components)``.

    ``base/pose`` and ``base/target`` points (pink / cyan), ``base/frame`` transform (3-D:
    translation and the pose's quaternion), ``base/progress`` and ``base/eta`` scalars (and
    ``base/route`` when the stream followed a route of a model of several), all on the
    ``wall_time`` timeline.
    """
    m = len(rows)
    offsets = pa.array(np.arange(m + 1, dtype=np.int32))
    timelines = {"wall_time": pa.array(rows.t_ns, type=pa.timestamp("ns"))}
    points = "Points2D" if dim == 2 else "Points3D"
    pose, target = (rows.position, rows.target) if dim != 2 else (
        rows.position[:, :2], rows.target[:, :2])
    out = [(f"{base}/pose", timelines, _chunk(
        points, offsets, positions=pose,
        colors=np.full(m, _packed(POSE_COLOR), dtype=np.uint32)))]
    if dim != 2:
        out.append((f"{base}/frame", timelines, _chunk(
            "Transform3D", offsets, translation=rows.position, quaternion=rows.orientation)))
    out += [
        (f"{base}/target", timelines, _chunk(
            points, offsets, positions=target,
            colors=np.full(m, _packed(TARGET_COLOR), dtype=np.uint32))),
        (f"{base}/progress", timelines, _chunk("Scalars", offsets, scalars=rows.progress)),
        (f"{base}/eta", timelines, _chunk("Scalars", offsets, scalars=rows.eta)),
    ]
    if np.any(rows.route >= 0):  # a model of several routes: the one the stream followed
        out.append((f"{base}/route", timelines,
                    _chunk("Scalars", offsets, scalars=rows.route.astype(np.float64))))
    return out


def send_live(rec: rr.RecordingStream, base: str, rows: LiveRows, dim: int = 3,
              fast: bool = True) -> None:
    """Log one stream's live rows under ``base`` (see :func:`live_chunks`) to ``rec``."""
    if fast and native_path():
        native = rec.to_native()
        for entity, timelines, components in live_chunks(base, rows, dim):
            _send_arrow_chunk(entity, timelines=timelines, components=components,
                              recording=native)
        return
    m = len(rows)
    index = [rr.TimeColumn("wall_time", timestamp=rows.t_ns.astype("datetime64[ns]"))]
    points = rr.Points2D if dim == 2 else rr.Points3D
    pose, target = (rows.position, rows.target) if dim != 2 else (
        rows.position[:, :2], rows.target[:, :2])
    rr.send_columns(f"{base}/pose", indexes=index, recording=rec, columns=points.columns(
        positions=pose, colors=np.full(m, _packed(POSE_COLOR), dtype=np.uint32)))
    if dim != 2:
        rr.send_columns(f"{base}/frame", indexes=index, recording=rec,
                        columns=rr.Transform3D.columns(translation=rows.position,
                                                       quaternion=rows.orientation))
    rr.send_columns(f"{base}/target", indexes=index, recording=rec, columns=points.columns(
        positions=target, colors=np.full(m, _packed(TARGET_COLOR), dtype=np.uint32)))
    rr.send_columns(f"{base}/progress", indexes=index, recording=rec,
                    columns=rr.Scalars.columns(scalars=rows.progress))
    rr.send_columns(f"{base}/eta", indexes=index, recording=rec,
                    columns=rr.Scalars.columns(scalars=rows.eta))
    if np.any(rows.route >= 0):
        rr.send_columns(f"{base}/route", indexes=index, recording=rec,
                        columns=rr.Scalars.columns(scalars=rows.route.astype(np.float64)))


@functools.cache
def status() -> str:
    """Which path live rows take with the installed rerun-sdk: what ``/healthz`` reports."""
    if native_path():
        return f"internals (rerun-sdk {INSTALLED}: rerun_bindings.send_arrow_chunk)"
    return (f"public API (rerun-sdk {INSTALLED}; the native path knows "
            f"{', '.join(v + 'x' for v in TESTED)})")
