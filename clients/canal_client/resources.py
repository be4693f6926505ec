"""What the client returns: plain frozen dataclasses, arrays as numpy.

Each ``from_json`` takes the service's JSON object for that resource (see the README's
Resources table) and nothing else.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "DemoCreated",
    "DemoSummary",
    "Demonstration",
    "Health",
    "Model",
    "ModelSummary",
    "Reproduction",
    "Skill",
]

FloatArray = NDArray[np.float64]


def _time(value: Any) -> datetime | None:
    return datetime.fromisoformat(value) if isinstance(value, str) else None


def _array(value: Any) -> FloatArray:
    return np.asarray(value, dtype=np.float64)


def _optional_array(value: Any) -> FloatArray | None:
    return None if value is None else _array(value)


@dataclass(frozen=True)
class Health:
    """``GET /healthz``: ``status`` is ``ok`` or ``degraded``."""

    status: str
    database: str
    recorder: dict[str, Any]
    version: str

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Health:
        return cls(status=d["status"], database=d["database"], recorder=dict(d["recorder"]),
                   version=d["version"])


@dataclass(frozen=True)
class Skill:
    """A skill with its counts and latest model version (``None`` before the first fit)."""

    name: str
    description: str
    dim: int
    created_at: datetime | None
    n_demonstrations: int
    n_models: int
    latest_model_version: int | None

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Skill:
        return cls(name=d["name"], description=d["description"], dim=int(d["dim"]),
                   created_at=_time(d.get("created_at")),
                   n_demonstrations=int(d["n_demonstrations"]), n_models=int(d["n_models"]),
                   latest_model_version=d.get("latest_model_version"))


@dataclass(frozen=True)
class DemoCreated:
    """A stored demonstration: its id, size and SHA-256 of the positions."""

    id: int
    n_points: int
    checksum: str

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> DemoCreated:
        return cls(id=int(d["id"]), n_points=int(d["n_points"]), checksum=d["checksum"])


@dataclass(frozen=True)
class DemoSummary:
    """A demonstration without its arrays."""

    id: int
    label: str | None
    n_points: int
    dim: int
    has_timestamps: bool
    has_orientations: bool
    source: str
    checksum: str
    created_at: datetime | None

    @staticmethod
    def _fields(d: dict[str, Any]) -> dict[str, Any]:
        return dict(id=int(d["id"]), label=d.get("label"), n_points=int(d["n_points"]),
                    dim=int(d["dim"]), has_timestamps=bool(d["has_timestamps"]),
                    has_orientations=bool(d["has_orientations"]), source=d["source"],
                    checksum=d["checksum"], created_at=_time(d.get("created_at")))

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> DemoSummary:
        return cls(**cls._fields(d))


@dataclass(frozen=True, eq=False)
class Demonstration(DemoSummary):
    """A demonstration with its arrays: positions (T, D), timestamps (T,), orientations (T, 4)."""

    positions: FloatArray
    timestamps: FloatArray | None
    orientations: FloatArray | None

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Demonstration:
        return cls(**cls._fields(d), positions=_array(d["positions"]),
                   timestamps=_optional_array(d.get("timestamps")),
                   orientations=_optional_array(d.get("orientations")))


@dataclass(frozen=True)
class ModelSummary:
    """One fitted model version and the options it was fitted with."""

    version: int
    created_at: datetime | None
    demo_ids: list[int]
    options: dict[str, Any]
    dim: int
    n_demos: int
    n_sections: int
    section_kind: str
    fit_seconds: float
    #: Whether the model learned orientation (its reproductions carry quaternions).
    has_orientation: bool

    @staticmethod
    def _fields(d: dict[str, Any]) -> dict[str, Any]:
        return dict(version=int(d["version"]), created_at=_time(d.get("created_at")),
                    demo_ids=[int(i) for i in d["demo_ids"]], options=dict(d["options"]),
                    dim=int(d["dim"]), n_demos=int(d["n_demos"]),
                    n_sections=int(d["n_sections"]), section_kind=d["section_kind"],
                    fit_seconds=float(d["fit_seconds"]),
                    has_orientation=bool(d.get("has_orientation", False)))

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> ModelSummary:
        return cls(**cls._fields(d))


@dataclass(frozen=True, eq=False)
class Model(ModelSummary):
    """A model version with its geometry.

    ``directrix`` (N, D), ``arclength`` (N,), ``radii`` (N,), ``tangents``/``normals`` (N, D),
    ``binormals`` (N, 3) or ``None`` in 2-D, ``bounds`` (2, D) as [min, max];
    ``sections`` the cross-section parameters; ``serialized`` the full canal_core model dict
    when asked for (``get_model(..., serialized=True)``).
    """

    directrix: FloatArray
    arclength: FloatArray
    radii: FloatArray
    tangents: FloatArray
    normals: FloatArray
    binormals: FloatArray | None
    bounds: FloatArray
    sections: dict[str, Any] | None
    serialized: dict[str, Any] | None

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Model:
        frames = d.get("frames") or {}
        return cls(**cls._fields(d), directrix=_array(d["directrix"]),
                   arclength=_array(d["arclength"]), radii=_array(d["radii"]),
                   tangents=_array(frames.get("tangents", [])),
                   normals=_array(frames.get("normals", [])),
                   binormals=_optional_array(frames.get("binormals")),
                   bounds=_array(d["bounds"]), sections=d.get("sections"),
                   serialized=d.get("serialized"))


@dataclass(frozen=True, eq=False)
class Reproduction:
    """One reproduced trajectory.

    ``positions`` (N', D) ends on the canal's last section; ``start`` (D,) is the start that was
    asked for; ``inside`` whether it was inside the canal; ``eta`` its ratio to the section's
    boundary (0 on the directrix, 1 on the boundary); ``section_index`` the section it was
    located at; ``projected`` whether it was outside and entered the canal over a short blend.
    ``times`` (N',) seconds from the start and ``velocities`` (N', D) follow the demonstrations'
    mean speed (None when the model has no time stamps and no duration was asked for);
    ``orientations`` (N', 4) unit quaternions qx, qy, qz, qw per position when the model has
    orientation (else ``None``); ``goal`` the goal asked for; ``notes`` what the service did
    that the request did not say (ignored or assumed).
    """

    positions: FloatArray
    start: FloatArray
    inside: bool
    eta: float
    section_index: int
    projected: bool
    model_version: int
    times: FloatArray | None = None
    velocities: FloatArray | None = None
    orientations: FloatArray | None = None
    goal: FloatArray | None = None
    notes: list[str] = field(default_factory=list)

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Reproduction:
        def optional(key: str) -> FloatArray | None:
            return None if d.get(key) is None else _array(d[key])

        return cls(positions=_array(d["positions"]), start=_array(d["start"]),
                   inside=bool(d["inside"]), eta=float(d["eta"]),
                   section_index=int(d["section_index"]), projected=bool(d["projected"]),
                   model_version=int(d["model_version"]), times=optional("times"),
                   velocities=optional("velocities"), orientations=optional("orientations"),
                   goal=optional("goal"), notes=[str(n) for n in d.get("notes") or []])
