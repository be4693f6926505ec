"""What the client returns: the contract's own models (:mod:`canal_protocol.schemas`).

Resources without arrays are the protocol's models themselves (``Skill`` is
:class:`canal_protocol.schemas.SkillOut`, ...). Resources with arrays are subclasses of the
protocol's models that hold numpy ``float64`` arrays where the protocol has lists of numbers:
same fields, same JSON (``model_dump(mode="json")`` gives the lists back), same JSON schema.
Nothing here lists a field the protocol does not, and tests diff these models against the
service's live OpenAPI document.
"""

from __future__ import annotations

from typing import Annotated, Any

import numpy as np
from numpy.typing import NDArray
from pydantic import (
    BeforeValidator,
    ConfigDict,
    Field,
    PlainSerializer,
    TypeAdapter,
    WithJsonSchema,
)

from canal_protocol.schemas import (
    DemonstrationCreated,
    DemonstrationOut,
    DemonstrationSummary,
    Frames,
    HealthOut,
    ModelOut,
    ReproductionBatchOut,
    ReproductionOut,
    SkillOut,
)
from canal_protocol.schemas import ModelSummary as ModelSummary

__all__ = [
    "DemoCreated",
    "DemoSummary",
    "Demonstration",
    "Health",
    "Model",
    "ModelFrames",
    "ModelSummary",
    "Reproduction",
    "ReproductionBatch",
    "Skill",
]

FloatArray = NDArray[np.float64]

#: ``GET /healthz``: ``status`` ok|degraded, ``database``, ``recorder``, ``bridge``, ``version``.
Health = HealthOut
#: A skill with its counts and latest model version (``None`` before the first fit).
Skill = SkillOut
#: A stored demonstration: its id, size and SHA-256 of the positions.
DemoCreated = DemonstrationCreated
#: A demonstration without its arrays.
DemoSummary = DemonstrationSummary


def _array(value: Any) -> FloatArray:
    if isinstance(value, np.ndarray) and value.dtype == np.float64:
        return value
    return np.asarray(value, dtype=np.float64)


def _rows(value: Any) -> FloatArray:
    array = _array(value)
    if array.ndim != 2:
        raise ValueError(f"expected rows of numbers (2-D), got shape {array.shape}")
    return array


def _vector(value: Any) -> FloatArray:
    array = _array(value)
    if array.ndim != 1:
        raise ValueError(f"expected a list of numbers (1-D), got shape {array.shape}")
    return array


def _listed(array: FloatArray) -> Any:
    return array.tolist()


# numpy in Python, the protocol's lists on the wire and in the JSON schema.
Rows = Annotated[
    FloatArray,
    BeforeValidator(_rows),
    PlainSerializer(_listed, return_type=list[list[float]]),
    WithJsonSchema(TypeAdapter(list[list[float]]).json_schema()),
]
Vector = Annotated[
    FloatArray,
    BeforeValidator(_vector),
    PlainSerializer(_listed, return_type=list[float]),
    WithJsonSchema(TypeAdapter(list[float]).json_schema()),
]

_ARRAYS = ConfigDict(arbitrary_types_allowed=True, frozen=True)


# The overrides below change a field's type from the protocol's lists to numpy arrays of the
# same values; mypy sees a changed attribute type (hence the ignores), pydantic the same field.


class Demonstration(DemonstrationOut):
    """A demonstration with its arrays: positions (T, D), timestamps (T,), orientations (T, 4)."""

    model_config = _ARRAYS

    positions: Rows  # type: ignore[assignment]
    timestamps: Vector | None  # type: ignore[assignment]
    orientations: Rows | None  # type: ignore[assignment]


class ModelFrames(Frames):
    """Per-section frames: tangents, normals (N, D), binormals (N, 3) or ``None`` in 2-D."""

    model_config = _ARRAYS

    tangents: Rows  # type: ignore[assignment]
    normals: Rows  # type: ignore[assignment]
    binormals: Rows | None  # type: ignore[assignment]


class Model(ModelOut):
    """A model version with its geometry.

    ``directrix`` (N, D), ``arclength`` (N,), ``radii`` (N,), ``frames`` (tangents and normals
    (N, D), binormals (N, 3) or ``None`` in 2-D; also as ``tangents``/``normals``/``binormals``),
    ``bounds`` (2, D) as [min, max]; ``sections`` the cross-section parameters; ``serialized``
    the full canal_core model dict when asked for (``get_model(..., serialized=True)``).
    """

    model_config = _ARRAYS

    directrix: Rows  # type: ignore[assignment]
    arclength: Vector  # type: ignore[assignment]
    radii: Vector  # type: ignore[assignment]
    frames: ModelFrames
    bounds: Rows  # type: ignore[assignment]

    @property
    def tangents(self) -> FloatArray:
        """``frames.tangents``, shape (N, D)."""
        return self.frames.tangents

    @property
    def normals(self) -> FloatArray:
        """``frames.normals``, shape (N, D)."""
        return self.frames.normals

    @property
    def binormals(self) -> FloatArray | None:
        """``frames.binormals``, shape (N, 3), ``None`` in 2-D."""
        return self.frames.binormals


class Reproduction(ReproductionOut):
    """One reproduced trajectory.

    ``positions`` (N', D) ends on the canal's last section; ``start`` (D,) is the start that was
    asked for; ``inside`` whether it was inside the canal; ``eta`` its ratio to the section's
    boundary (0 on the directrix, 1 on the boundary); ``section_index`` the section it was
    located at; ``projected`` whether it was outside and entered the canal over a short blend.
    ``times`` (N',) seconds from the start and ``velocities`` (N', D) follow the demonstrations'
    mean speed (None when the model has no time stamps and no duration was asked for);
    ``orientations`` (N', 4) unit quaternions qx, qy, qz, qw per position when the model has
    orientation (else ``None``); ``goal`` the goal asked for; ``ratios`` (N',) how far out each
    position is (the start's ratio, then each position's in its section); ``notes`` what the
    service did that the request did not say (ignored or assumed).
    """

    model_config = _ARRAYS

    positions: Rows  # type: ignore[assignment]
    start: Vector  # type: ignore[assignment]
    times: Vector | None = None  # type: ignore[assignment]
    velocities: Rows | None = None  # type: ignore[assignment]
    orientations: Rows | None = None  # type: ignore[assignment]
    goal: Vector | None = None  # type: ignore[assignment]
    ratios: Vector = Field(default_factory=lambda: np.zeros(0))  # type: ignore[assignment]


class ReproductionBatch(ReproductionBatchOut):
    """Reproductions in the order of the request's ``starts``."""

    model_config = _ARRAYS

    reproductions: list[Reproduction]  # type: ignore[assignment]
