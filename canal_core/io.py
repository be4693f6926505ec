"""The canal model format (``canal-model`` version 1): a canal as a JSON-able dict and back.

Floats are written with ``repr`` precision, so every float64 survives the round trip. Keys
added after version 1 shipped are optional on reading (older models default them).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, cast

import numpy as np

from .clocks import CLOCKS, Clock
from .corrections import AppliedCorrection
from .cross_sections import CrossSections, section_kind, section_kinds
from .errors import ModelFormatError
from .options import FitOptions
from .orientation import OrientationModel
from .validation import FloatArray

if TYPE_CHECKING:
    from .model import Canal

FORMAT = "canal-model"
FORMAT_VERSION = 1


def canal_dict(canal: Canal) -> dict[str, Any]:
    """A JSON-able dict (format ``canal-model`` version 1) of ``canal`` that round-trips
    exactly through :func:`canal_fields`."""
    return {
        "format": FORMAT,
        "version": FORMAT_VERSION,
        "dim": canal.dim,
        "options": canal.options.to_dict(),
        "directrix": canal.directrix.tolist(),
        "tangents": canal.tangents.tolist(),
        "normals": canal.normals.tolist(),
        "binormals": None if canal.binormals is None else canal.binormals.tolist(),
        "arclength": canal.arclength.tolist(),
        "sections": canal.sections.to_dict(),
        "section_points": canal.section_points.tolist(),
        "end_depths": canal.end_depths.tolist(),
        # Absent in models saved before orientation existed; None when not learned.
        "orientation": None if canal.orientation is None else canal.orientation.to_dict(),
        # Optional keys (absent in models written before them; from_dict defaults them).
        "section_times": None if canal.section_times is None else canal.section_times.tolist(),
        "section_pace": None if canal.section_pace is None else canal.section_pace.tolist(),
        "envelope_margin": canal.envelope_margin,
        "parent": canal.parent,
        "corrections": [c.to_dict() for c in canal.corrections],
        "clock": canal.clock,
    }


def canal_fields(data: dict[str, Any]) -> dict[str, Any]:
    """The :class:`~canal_core.model.Canal` fields of a dict written by :func:`canal_dict`,
    checked; raises :class:`ModelFormatError`."""
    try:
        if data.get("format") != FORMAT or data.get("version") != FORMAT_VERSION:
            raise ModelFormatError(
                f"expected format {FORMAT!r} version {FORMAT_VERSION}, got "
                f"{data.get('format')!r} version {data.get('version')!r}",
                field="format",
            )
        arr = {
            k: np.asarray(data[k], dtype=np.float64)
            for k in ("directrix", "tangents", "normals", "arclength", "section_points", "end_depths")
        }
        dim = int(data["dim"])
        n = arr["directrix"].shape[0]
        sec = dict(data["sections"])
        kind = sec.pop("kind")
        if kind not in section_kinds(dim):
            raise ModelFormatError(
                f"expected a {dim}-D cross-section kind among {', '.join(map(repr, section_kinds(dim)))}, "
                f"got {kind!r}",
                field="sections",
            )
        params = {k: np.asarray(v, dtype=np.float64) for k, v in sec.items()}
        expected_params = section_kind(kind).params
        if sorted(params) != sorted(expected_params):
            raise ModelFormatError(
                f"expected {kind} section parameters {', '.join(expected_params)}, got {', '.join(params)}",
                field="sections",
            )
        binormals = None if data["binormals"] is None else np.asarray(data["binormals"], dtype=np.float64)
        expected = {
            "directrix": (n, dim), "tangents": (n, dim), "normals": (n, dim), "arclength": (n,),
            "end_depths": (2,),
        }
        for key, shape in expected.items():
            if arr[key].shape != shape:
                raise ModelFormatError(f"expected {key} of shape {shape}, got {arr[key].shape}", field=key)
        if binormals is not None and binormals.shape != (n, dim):
            raise ModelFormatError(f"expected binormals of shape {(n, dim)}, got {binormals.shape}",
                                   field="binormals")
        crossings = arr["section_points"]
        if crossings.ndim != 3 or crossings.shape[0] != n or crossings.shape[2] != dim - 1:
            raise ModelFormatError(f"expected section_points of shape ({n}, demos, {dim - 1}), "
                                   f"got {crossings.shape}", field="section_points")
        # a NaN in a stored array reaches every answer as NaN (null over JSON)
        for key, values in (*arr.items(), ("binormals", binormals), *params.items()):
            if values is not None and not np.isfinite(values).all():
                raise ModelFormatError(f"expected finite numbers in {key}, got NaN or Inf",
                                       field="sections" if key in params else key)
        if any(v.shape[0] != n for v in params.values()):
            raise ModelFormatError(f"expected {n} cross-sections in every parameter", field="sections")
        raw_orientation = data.get("orientation")
        orientation = (
            None if raw_orientation is None else OrientationModel.from_dict(raw_orientation, n)
        )
        return dict(
            directrix=arr["directrix"],
            tangents=arr["tangents"],
            normals=arr["normals"],
            binormals=binormals,
            arclength=arr["arclength"],
            sections=CrossSections(kind, params),
            section_points=arr["section_points"],
            end_depths=arr["end_depths"],
            # Models saved before frame smoothing existed had frames of the raw directrix.
            options=FitOptions(**{"frame_smoothing": 0.0, **data["options"]}),
            orientation=orientation,
            section_times=_optional_times(data.get("section_times"), n),
            section_pace=_optional_times(data.get("section_pace"), n, "section_pace"),
            envelope_margin=float(data.get("envelope_margin", 0.0)),
            # Absent in models written before corrections existed.
            parent=None if data.get("parent") is None else str(data["parent"]),
            corrections=tuple(
                AppliedCorrection.from_dict(c, n, dim) for c in data.get("corrections") or ()
            ),
            # Absent in models written before the clock was chosen per fit.
            clock=_clock(data.get("clock", "arc")),
        )
    except ModelFormatError:
        raise
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ModelFormatError(f"malformed canal model: {exc!r}") from exc


def _clock(value: Any) -> Clock:
    if value not in CLOCKS:
        raise ModelFormatError(f"expected clock among {', '.join(map(repr, CLOCKS))}, got {value!r}",
                               field="clock")
    return cast(Clock, value)


def _optional_times(values: Any, n: int, name: str = "section_times") -> FloatArray | None:
    if values is None:
        return None
    times = np.asarray(values, dtype=np.float64)
    if times.shape != (n,) or not np.all(np.isfinite(times)) or np.any(np.diff(times) < 0.0):
        raise ModelFormatError(
            f"expected {name} of shape ({n},), finite and non-decreasing, got shape {times.shape}",
            field=name,
        )
    return times
