"""Pydantic models at the HTTP boundary. Field names and shapes here are the public contract."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Annotated, Any, Generic, Literal, TypeVar

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, model_validator

SKILL_NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$"
MAX_BATCH_STARTS = 1000
# Ids and versions fit a 32-bit SQL integer; larger numbers cannot name anything we stored,
# and would overflow the database driver instead of giving a clean 404.
MAX_ID = 2**31 - 1
# PostgreSQL text cannot hold NUL; refuse it at the boundary on every backend.
NO_NUL = r"^[^\x00]*$"

Id = Annotated[int, Field(ge=1, le=MAX_ID)]


def _utc(value: datetime | None) -> datetime | None:
    # SQLite hands back naive datetimes; every time we store is UTC.
    if value is not None and value.tzinfo is None:
        return value.replace(tzinfo=UTC)
    return value


UtcDatetime = Annotated[datetime | None, AfterValidator(_utc)]

T = TypeVar("T")


class _In(BaseModel):
    # Unknown keys are usually typos ("position"); say so instead of ignoring them.
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class ErrorDetail(BaseModel):
    """One problem with a request."""

    type: str = Field(description="Stable machine-readable kind, e.g. invalid_input, not_found.")
    field: str | None = Field(description="The request part at fault, e.g. positions[3].")
    message: str
    details: list[dict[str, Any]] | None = None


class ErrorResponse(BaseModel):
    """Body of every 4xx/5xx."""

    error: ErrorDetail


class Page(BaseModel, Generic[T]):
    """A page of a list: ``items`` from ``offset``, at most ``limit``, ``total`` overall."""

    items: list[T]
    total: int
    offset: int
    limit: int


# ---- skills ----------------------------------------------------------------------------------


class SkillCreate(_In):
    """A new skill: a name unique in this service, a dimension fixed for life."""

    name: str = Field(pattern=SKILL_NAME_PATTERN, examples=["pour"],
                      description="Letters, digits, '.', '_', '-'; up to 64 characters.")
    description: str = Field("", max_length=4000, pattern=NO_NUL)
    dim: Literal[2, 3] = Field(3, description="2 for planar skills, 3 for spatial ones.")


class SkillOut(BaseModel):
    """A skill with its counts."""

    name: str
    description: str
    dim: int
    created_at: UtcDatetime
    n_demonstrations: int
    n_models: int
    latest_model_version: int | None


# ---- demonstrations --------------------------------------------------------------------------


class DemonstrationIn(_In):
    """One demonstration as JSON. Positions are (T, D) rows, T >= 4."""

    positions: list[list[float]] = Field(
        description="(T, D) rows of x, y[, z]; D is the skill's dimension.",
        examples=[[[0, 0, 0], [1, 0, 0], [2, 0.1, 0], [3, 0, 0]]],
    )
    timestamps: list[float] | None = Field(
        None, description="(T,) strictly increasing seconds, optional."
    )
    orientations: list[list[float]] | None = Field(
        None, description="(T, 4) unit quaternions qx, qy, qz, qw, optional."
    )
    label: str | None = Field(None, max_length=256, pattern=NO_NUL)


class DemonstrationCreated(BaseModel):
    """What a stored demonstration got: its id, size and checksum."""

    id: int
    n_points: int
    checksum: str = Field(description="SHA-256 of the positions as little-endian float64, row-major.")


class DemonstrationSummary(BaseModel):
    """A demonstration without its arrays."""

    id: int
    label: str | None
    n_points: int
    dim: int
    has_timestamps: bool
    has_orientations: bool
    source: str = Field(description="json, csv, npy or mcap.")
    checksum: str
    created_at: UtcDatetime


class DemonstrationOut(DemonstrationSummary):
    """A demonstration with its arrays."""

    positions: list[list[float]]
    timestamps: list[float] | None
    orientations: list[list[float]] | None


# ---- fitting and models ----------------------------------------------------------------------


class FitRequest(_In):
    """canal_core fit options; every field has the canal_core default."""

    cross_section: Literal["circle", "mec", "ellipse", "spline"] = "circle"
    frames: Literal["rmf", "frenet"] = "rmf"
    alignment: Literal["spline", "dtw"] = "spline"
    directrix: Literal["mean", "gmr"] = "mean"
    n_samples: int = Field(200, ge=2, le=5000)
    frame_smoothing: float = Field(
        0.02, ge=0.0, le=0.25,
        description="Frames are computed on the directrix smoothed by a Gaussian of this "
                    "fraction of n_samples; 0 = the paper's raw frames.")
    by_time: bool = Field(
        False,
        description="Align demonstrations by their timestamps (when every one has them) "
                    "instead of by arc length. Arc length is the default: on LASA "
                    "leave-one-out it follows held-out demos closer (BENCHMARKS.md).")
    demo_ids: list[Id] | None = Field(
        None, max_length=10000, description="Fit only these demonstrations (default: all)."
    )


class ModelSummary(BaseModel):
    """One fitted model version."""

    version: int
    created_at: UtcDatetime
    demo_ids: list[int]
    options: dict[str, Any]
    dim: int
    n_demos: int
    n_sections: int
    section_kind: str
    fit_seconds: float


class Frames(BaseModel):
    """Per-section frame vectors along the directrix."""

    tangents: list[list[float]]
    normals: list[list[float]]
    binormals: list[list[float]] | None


class ModelOut(ModelSummary):
    """A model version with its geometry."""

    directrix: list[list[float]]
    arclength: list[float]
    radii: list[float]
    frames: Frames
    bounds: list[list[float]] = Field(description="[[min...], [max...]] corners of the canal.")
    sections: dict[str, Any] | None = Field(
        None, description="Cross-section parameters as serialised by canal_core."
    )
    serialized: dict[str, Any] | None = Field(
        None, description="The full canal_core model (Canal.from_dict input), with ?serialized=true."
    )


# ---- reproductions ---------------------------------------------------------------------------


class ReproductionRequest(_In):
    """Reproduce from one ``start`` or from a batch of ``starts`` (exactly one of the two)."""

    start: list[float] | None = Field(None, min_length=2, max_length=3, examples=[[0.0, 0.0, 0.0]])
    starts: list[list[float]] | None = Field(None, min_length=1, max_length=MAX_BATCH_STARTS)
    model: Literal["latest"] | Id = Field(
        "latest", description="'latest' or a model version number."
    )
    outside: Literal["project", "raise"] = Field(
        "project",
        description="A start outside the canal enters it over a short blend (200, inside=false, "
        "projected=true), or is refused with 422 when 'raise'.",
    )
    goal: list[float] | None = Field(
        None, min_length=2, max_length=3,
        description="End the reproduction here: the canal is smoothly deformed so its end moves "
        "to the goal (the start region is untouched).",
    )
    duration: float | None = Field(
        None, gt=0, allow_inf_nan=False,
        description="Seconds: the times are stretched to end there (evenly paced along the path "
        "when the model has no time stamps).",
    )
    start_orientation: list[float] | None = Field(
        None, min_length=4, max_length=4, description="Unit quaternion [qx, qy, qz, qw]."
    )

    @model_validator(mode="after")
    def _one_of_start_or_starts(self) -> ReproductionRequest:
        if (self.start is None) == (self.starts is None):
            raise ValueError("give exactly one of 'start' or 'starts'")
        return self


class ReproductionOut(BaseModel):
    """One reproduced trajectory."""

    positions: list[list[float]]
    start: list[float]
    inside: bool
    eta: float
    section_index: int
    projected: bool
    model_version: int
    times: list[float] | None = Field(
        None, description="Seconds from the start, following the demonstrations' mean speed."
    )
    velocities: list[list[float]] | None = None
    orientations: list[list[float]] | None = None
    goal: list[float] | None = None
    notes: list[str] = Field(default_factory=list)


class ReproductionBatchOut(BaseModel):
    """Reproductions in the order of ``starts``."""

    reproductions: list[ReproductionOut]


class HealthOut(BaseModel):
    """Liveness and the state of the parts the service depends on."""

    status: Literal["ok", "degraded"]
    database: str
    recorder: dict[str, Any]
    bridge: dict[str, Any] = Field(default_factory=lambda: {"status": "disabled"},
                                   description="The live Zenoh bridge (status ok|down|disabled).")
    version: str
