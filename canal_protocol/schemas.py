"""Pydantic models at the HTTP boundary. Field names and shapes here are the public contract."""

from __future__ import annotations

import itertools
import json
from datetime import UTC, datetime
from typing import Annotated, Any, Generic, Literal, TypeVar

import numpy as np
import numpy.typing as npt
import orjson
from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    Strict,
    TypeAdapter,
    ValidationError,
    ValidatorFunctionWrapHandler,
    WrapValidator,
    model_validator,
)
from pydantic_core import PydanticCustomError

from canal_core import obstacles as canal_obstacles

from . import options
from .options import (
    Alignment,
    CorrectionKind,
    CrossSection,
    Directrix,
    FrameKind,
    OutsideRule,
    Persistence,
)

SKILL_NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$"
#: :data:`SKILL_NAME_PATTERN` in words, for error messages.
SKILL_NAME_WORDS = ("expected a skill name of 1 to 64 letters, digits, '.', '_' or '-', "
                    "starting with a letter or digit")
MAX_BATCH_STARTS = 1000
# Ids and versions fit a 32-bit SQL integer; larger numbers cannot name anything we stored,
# and would overflow the database driver instead of giving a clean 404.
MAX_ID = 2**31 - 1
# PostgreSQL text cannot hold NUL; refuse it at the boundary on every backend.
NO_NUL = r"^[^\x00]*$"

Id = Annotated[int, Field(ge=1, le=MAX_ID)]


def _model_ref(value: Any, handler: ValidatorFunctionWrapHandler) -> Any:
    # The union's own errors name its branch ("model.literal['latest']: Input should be
    # 'latest'") whatever was sent, which reads as if no number were allowed.
    try:
        return handler(value)
    except ValidationError:
        raise PydanticCustomError(
            "model_version", "expected 'latest' or a model version from 1 to {largest}, got {got}",
            {"largest": MAX_ID, "got": shown_value(value)},
        ) from None


def shown_value(value: Any) -> str:
    """What a client sent, for an error message: a JSON scalar as written, else its kind."""
    # json, not orjson: a JSON integer past 64 bits is still what came.
    if isinstance(value, str | int | float | bool | None):
        text = json.dumps(value)
        return text if len(text) <= 40 else text[:37] + "..."
    if isinstance(value, dict):
        return "an object"
    return "a list" if isinstance(value, list) else type(value).__name__


def _dimension(value: Any, handler: ValidatorFunctionWrapHandler) -> Any:
    # A Literal of integers takes 3.0 (it equals 3): a dimension is a whole JSON number.
    if type(value) is not int:
        raise PydanticCustomError("dimension", "expected 2 or 3 (a whole number), got {got}",
                                  {"got": shown_value(value)})
    return handler(value)


#: A skill's dimension: 2 or 3, a JSON integer.
Dimension = Annotated[Literal[2, 3], WrapValidator(_dimension)]
#: 'latest' or a model version (a JSON number, not a string of one).
ModelRef = Annotated[Literal["latest"] | Id, WrapValidator(_model_ref)]
# A coordinate is a JSON number: strict, so `true` or "1" is refused instead of becoming 1.0
# (integers still count as numbers).
Coordinate = Annotated[float, Strict()]


def _utc(value: datetime | None) -> datetime | None:
    # SQLite hands back naive datetimes; every time we store is UTC.
    if value is not None and value.tzinfo is None:
        return value.replace(tzinfo=UTC)
    return value


UtcDatetime = Annotated[datetime | None, AfterValidator(_utc)]


def _distinct(ids: list[int] | None) -> list[int] | None:
    """A selection names each demonstration once: a repeat would be fitted once, not twice."""
    if ids is not None:
        seen: set[int] = set()
        for i, demo_id in enumerate(ids):
            if demo_id in seen:
                raise ValueError(f"expected distinct demonstration ids, got {demo_id} again at "
                                 f"demo_ids[{i}]")
            seen.add(demo_id)
    return ids

T = TypeVar("T")


class _In(BaseModel):
    # Unknown keys are usually typos ("position"); say so instead of ignoring them.
    # Strict: a JSON value of another type is refused, not coerced. `true` is not route 1,
    # model version 1 or a 1.0 coordinate, and "no" is not false (an integer still counts
    # as a number).
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)


class ErrorDetail(BaseModel):
    """One problem with a request."""

    type: str = Field(description="Stable machine-readable kind, e.g. invalid_input, not_found.")
    field: str | None = Field(None, description="The request part at fault, e.g. positions[3].")
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
    dim: Dimension = Field(3, description="2 for planar skills, 3 for spatial ones.")


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

    positions: list[list[Coordinate]] = Field(
        description="(T, D) rows of x, y[, z] (JSON numbers); D is the skill's dimension.",
        examples=[[[0, 0, 0], [1, 0, 0], [2, 0.1, 0], [3, 0, 0]]],
    )
    timestamps: list[Coordinate] | None = Field(
        None, description="(T,) seconds, optional, stored as sent. Equal stamps (a polling logger) and isolated late samples are repaired when the canal is fitted; time going back for more than one sample is refused."
    )
    orientations: list[list[Coordinate]] | None = Field(
        None, description="(T, 4) unit quaternions qx, qy, qz, qw, optional."
    )
    label: str | None = Field(None, max_length=options.MAX_DEMO_LABEL, pattern=NO_NUL)


_DEMO_KEYS = frozenset({"positions", "timestamps", "orientations", "label"})
# What a JSON array of numbers is made of: digits, signs, exponents, separators, whitespace.
_ARRAY_BYTES = b"0123456789.eE+-,[] \t\r\n"


def demonstration_from_json(raw: bytes) -> DemonstrationIn:
    """Parse an upload's JSON body into a :class:`DemonstrationIn`.

    The common body (numbers in nested lists, maybe a plain label) takes a fast path:
    orjson, then one numpy conversion per array, ~3x less CPU than validating 3,000 floats
    one by one; its arrays arrive as float64 ndarrays. Anything else, and anything the fast
    path cannot prove equal to what the model accepts, goes through
    ``model_validate_json``, which gives the same values or the errors naming the field.
    """
    fast = _fast_demonstration(raw)
    return fast if fast is not None else DemonstrationIn.model_validate_json(raw)


def _fast_demonstration(raw: bytes) -> DemonstrationIn | None:
    # No escapes: every string in the body is then byte for byte what orjson writes for it.
    if b"\\" in raw:
        return None
    try:
        data = orjson.loads(raw)
    except orjson.JSONDecodeError:
        return None
    if not isinstance(data, dict) or "positions" not in data or not data.keys() <= _DEMO_KEYS:
        return None
    label = data.get("label")
    if label is not None and (not isinstance(label, str) or len(label) > options.MAX_DEMO_LABEL):
        return None
    # Delete every byte a number array may hold from the body and from its skeleton (the
    # same object, arrays emptied, written back): equal leftovers mean the arrays added
    # nothing else, so they hold numbers and lists only, no string, boolean or null
    # (strict, as the model demands). One pass over the body, in C.
    skeleton = {key: [] if isinstance(value, list) else value for key, value in data.items()}
    if raw.translate(None, _ARRAY_BYTES) != orjson.dumps(skeleton).translate(None, _ARRAY_BYTES):
        return None
    arrays: dict[str, Any] = {}
    # Widths other than these take the slow path, whose row-by-row checks name the bad row.
    for key, widths in (("positions", (2, 3)), ("timestamps", ()), ("orientations", (4,))):
        value = data.get(key)
        if value is None:
            if key == "positions":
                return None
            arrays[key] = None
            continue
        array = _float_array(value, widths)
        if array is None:
            return None
        arrays[key] = array
    return DemonstrationIn.model_construct(label=label, **arrays)


def _float_array(value: Any, widths: tuple[int, ...]) -> npt.NDArray[np.float64] | None:
    """A non-empty list of numbers (no widths) or of rows of one width in ``widths``, as a
    float64 array; None for anything else. The elements are known to be numbers or lists.

    Rows go through one flat iterator into ``np.fromiter``: ~3x less CPU than ``np.array``
    on nested lists, which discovers the shape and the type of every element first.
    """
    if not isinstance(value, list) or not value:
        return None
    try:
        if not widths:
            flat = np.array(value, dtype=np.float64)
            return flat if flat.ndim == 1 else None
        width = len(value[0])
        if width not in widths or set(map(len, value)) != {width}:
            return None
        return np.fromiter(itertools.chain.from_iterable(value), dtype=np.float64,
                           count=len(value) * width).reshape(len(value), width)
    except (TypeError, ValueError, OverflowError):  # a number where a row was due, or deeper lists
        return None


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
    """canal_core fit options; every field left out takes canal_core's default.

    Names, defaults and limits come from :mod:`canal_protocol.options` (derived from
    :mod:`canal_core.options`), never written out here.
    """

    cross_section: CrossSection = options.DEFAULTS.cross_section
    frames: FrameKind = options.DEFAULTS.frames
    alignment: Alignment = options.DEFAULTS.alignment
    directrix: Directrix = options.DEFAULTS.directrix
    n_samples: int = Field(
        options.DEFAULTS.n_samples, ge=options.MIN_SAMPLES, le=options.MAX_SAMPLES,
        description="N, the number of cross-sections.")
    frame_smoothing: float = Field(
        options.DEFAULTS.frame_smoothing, ge=0.0, le=options.MAX_FRAME_SMOOTHING,
        description="Frames are computed on the directrix smoothed by a Gaussian of this "
                    "fraction of its length; 0 = the paper's raw frames.")
    by_time: bool | None = Field(
        None,
        description="true: align the demonstrations by their time stamps; false: by arc length; "
                    "left out: by the fit's timing test (the time stamps, or a steady logger's "
                    "sample index, blended with arc length when the demonstrations keep one "
                    "rhythm, else arc length). The model's options say which clock was used "
                    "(clock).")
    demo_ids: Annotated[list[Id] | None, AfterValidator(_distinct)] = Field(
        None, min_length=2, max_length=10000,
        description="Fit only these demonstrations, at least 2, each once (default: all)."
    )
    keep_corrections: bool = Field(
        True,
        description="Re-apply the skill's corrections (those of its latest model version) "
                    "to the new canal: the fit is stored, then a version with the corrections "
                    "(whose parent is the fit) becomes the latest. False: the plain fit is the "
                    "latest and the corrections are left behind.")
    orientation: bool = Field(
        True,
        description="Learn the orientation along the canal when every demonstration has "
                    "orientations (false: positions only). The model's options say whether "
                    "it was learned.")
    routes: int | None = Field(
        None, ge=1, le=options.MAX_ROUTES,
        description="Demonstrations that go clearly different ways are split into routes, one "
                    "canal each (docs/routes.md). Left out: split where they are more than "
                    "route_separation apart; 1: one canal of all, never split; N: exactly N "
                    "routes (at most half the demonstrations).")
    route_separation: float = Field(
        options.ROUTE_SEPARATION, ge=options.MIN_ROUTE_SEPARATION, le=options.MAX_ROUTE_SEPARATION,
        description="Where routes split when 'routes' is left out: the demonstrations' mean "
                    "distance, as a share of their median path length.")


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
    has_orientation: bool = Field(
        False, description="Whether the model learned orientation (every demo had "
                           "orientations): reproductions then answer one quaternion per position.")
    parent_version: int | None = Field(
        None, description="The version this one was refined from by a correction (or, after "
                          "a refit that kept the corrections, the plain fit); null for a fit.")
    corrections: list[int] = Field(
        default_factory=list,
        description="Ids of the corrections applied to this version since its fit, in order.")
    notes: list[str] = Field(
        default_factory=list,
        description="What the service did that the request could not tell (e.g. a correction "
                    "that no longer applies after a refit).")
    routes: int = Field(
        1, description="How many routes the model has: one canal each (1: a single canal).")
    demo_routes: list[int] | None = Field(
        None, description="The route (0, 1, ...) of each demonstration, in the order of "
                          "demo_ids; null when the model has one route.")


# ---- corrections ------------------------------------------------------------------------------


class CorrectionIn(_In):
    """A person's correction of a skill's canal: a short path over part of it and its kind."""

    kind: CorrectionKind = Field(
        description="include: this path is right too (the canal grows locally to hold it); "
                    "exclude: the robot was pushed away from where it went (the canal narrows "
                    "on that side, keeping the distance the person showed).")
    samples: list[list[Coordinate]] = Field(
        max_length=options.MAX_CORRECTION_SAMPLES,
        description=f"(M, D) rows of x, y[, z] along the canal, M >= "
                    f"{options.MIN_CORRECTION_SAMPLES}; D is the skill's dimension.",
        examples=[[[0.1, 0.02, 0.0], [0.2, 0.03, 0.0], [0.3, 0.03, 0.0], [0.4, 0.02, 0.0]]])
    timestamps: list[Coordinate] | None = Field(
        None, description="(M,) seconds, optional; kept with the correction.")
    orientations: list[list[Coordinate]] | None = Field(
        None, description="(M, 4) unit quaternions, optional; kept with the correction.")
    plan: list[list[Coordinate]] | None = Field(
        None, max_length=options.MAX_CORRECTION_SAMPLES,
        description="exclude only, optional: (P, D) the path the robot was on before the push "
                    "(default: the model's reproduction from the first sample); an include "
                    "with a plan is refused (422 naming plan).")
    model: ModelRef = Field(
        "latest", description="The model version corrected; the result is always the new latest.")
    weight: float = Field(
        1.0, gt=0.0, le=options.MAX_CORRECTION_WEIGHT,
        description="How much an include counts against one demonstration (exclude ignores it).")
    label: str = Field("", max_length=options.MAX_CORRECTION_LABEL, pattern=NO_NUL)
    route: int | None = Field(
        None, ge=0, le=options.MAX_ROUTES - 1,
        description="A model of several routes: the route whose canal is corrected (null: every "
                    "route's canal the samples pass through, and the canal of all; refused "
                    "when no route's canal takes them).")


class CorrectionOut(BaseModel):
    """A stored correction."""

    id: int
    kind: str
    label: str
    weight: float
    n_points: int
    base_version: int = Field(description="The model version it was first applied to.")
    model_version: int = Field(description="The model version it made.")
    first_section: int
    last_section: int
    created_at: UtcDatetime
    undone: bool = Field(description="True when the skill's latest model version does not hold "
                                     "it (undone, or left behind by a refit); it stays listed.")
    route: int | None = Field(
        None, description="The route it corrects (null: every route it passes through, or the "
                          "model has one route).")


class CorrectionPath(CorrectionOut):
    """A stored correction with its path, as it was sent (glitches included)."""

    samples: list[list[float]] = Field(description="(M, D) the corrected path.")
    timestamps: list[float] | None = Field(None, description="(M,) seconds, when sent.")
    orientations: list[list[float]] | None = Field(
        None, description="(M, 4) unit quaternions, when sent.")
    plan: list[list[float]] | None = Field(
        None, description="exclude: (P, D) the path the robot was on before the push, when sent.")


class CorrectedModel(ModelSummary):
    """The model version a correction (or an undo) made, and the correction."""

    correction: CorrectionOut


class Frames(BaseModel):
    """Per-section frame vectors along the directrix."""

    tangents: list[list[float]]
    normals: list[list[float]]
    binormals: list[list[float]] | None


class RouteCanal(BaseModel):
    """One route's canal in a model of several routes."""

    route: int
    n_demos: int
    directrix: list[list[float]]
    radii: list[float]


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
        None, description="The full canal_core model, with ?serialized=true: Canal.from_dict "
                          "input, or with several routes the 'canal-routes' dict "
                          "(canal_core.routes.routes_from_dict reads both)."
    )
    route_canals: list[RouteCanal] | None = Field(
        None, description="With several routes, each route's canal (the fields above are the "
                          "canal of all the demonstrations); null with one route.")


# ---- reproductions ---------------------------------------------------------------------------


# ---- scenes: obstacles ------------------------------------------------------------------------

#: Most obstacles in one scene, and in one request.
MAX_OBSTACLES = canal_obstacles.MAX_OBSTACLES
ObstacleKind = canal_obstacles.ObstacleKind
PositiveLength = Annotated[float, Strict(), Field(gt=0, allow_inf_nan=False)]


_QUATERNION = TypeAdapter(list[Coordinate], config=ConfigDict(strict=True, allow_inf_nan=False))


def _rotation(value: Any, handler: ValidatorFunctionWrapHandler) -> Any:
    # A list is a quaternion: its own errors name the component at fault. Anything else is
    # an angle or wrong; the union's errors would name both branches ("Input should be a
    # valid list", "rotation.float: ..."), which read as if an angle were not allowed.
    if isinstance(value, list):
        return _QUATERNION.validate_python(value)
    try:
        return handler(value)
    except ValidationError:
        raise PydanticCustomError(
            "rotation", "expected [qx, qy, qz, qw] (3-D) or a finite angle in radians (2-D), "
                        "got {got}", {"got": shown_value(value)},
        ) from None


#: A box's orientation: a quaternion [qx, qy, qz, qw] in 3-D, an angle in radians in 2-D.
Rotation = Annotated[list[Coordinate] | Coordinate, WrapValidator(_rotation)]


class ObstacleIn(_In):
    """One obstacle; which keys it takes depends on ``kind`` (checked against the skill's
    dimension by the service, naming the key at fault)::

        sphere (3-D), disc (2-D): center, radius
        box: center, half_extents, rotation (optional: [qx, qy, qz, qw] in 3-D, an angle in
             radians in 2-D; axis-aligned when absent)
        capsule: a, b (the ends of its axis), radius

    Every obstacle keeps ``clearance`` (>= 0, in the skill's units) between it and a path.
    """

    kind: ObstacleKind = Field(examples=["sphere"])
    center: list[Coordinate] | None = Field(None, min_length=2, max_length=3, examples=[[0.4, 0.0, 0.3]])
    radius: PositiveLength | None = Field(None, examples=[0.05])
    half_extents: list[PositiveLength] | None = Field(None, min_length=2, max_length=3)
    rotation: Rotation | None = Field(
        None, description="Box orientation: [qx, qy, qz, qw] (3-D) or radians (2-D).")
    a: list[Coordinate] | None = Field(None, min_length=2, max_length=3)
    b: list[Coordinate] | None = Field(None, min_length=2, max_length=3)
    clearance: float = Field(0.0, ge=0, allow_inf_nan=False,
                             description="Distance every path keeps from the surface.")
    name: str | None = Field(None, max_length=64, pattern=NO_NUL)

    def as_dict(self) -> dict[str, Any]:
        """The keys that were given (canal_core's form)."""
        return self.model_dump(exclude_none=True)


class SceneIn(_In):
    """A skill's scene: what stands in its canal. It replaces the previous one."""

    obstacles: list[ObstacleIn] = Field(max_length=MAX_OBSTACLES)


class SceneOut(BaseModel):
    """A skill's scene: every reproduction and live stream of the skill goes around it.

    ``version`` counts the scene's changes (0: never set); the last write wins.
    """

    skill: str
    version: int
    obstacles: list[dict[str, Any]]
    updated_at: UtcDatetime = None


class BlockedOut(BaseModel):
    """Where obstacles close the canal: the reproduction ends at the section before."""

    section: int = Field(description="The cross-section the path cannot enter.")
    reason: Literal["closed", "unreachable", "start"] = Field(
        description="closed: no clear point left in the section inside the canal; unreachable: "
                    "none within the demonstrations' largest step; start: the start is inside an "
                    "obstacle or its clearance deeper than 64 such steps back out of.")
    obstacles: list[int] = Field(
        description="Indices (in the scene used) of the obstacles in the way (never empty): for "
                    "closed those that take the section, else those the steps into it run into.")


class ReproductionRequest(_In):
    """Reproduce from one ``start`` or from a batch of ``starts`` (exactly one of the two)."""

    start: list[Coordinate] | None = Field(None, min_length=2, max_length=3, examples=[[0.0, 0.0, 0.0]])
    starts: list[list[Coordinate]] | None = Field(None, min_length=1, max_length=MAX_BATCH_STARTS)
    model: ModelRef = Field(
        "latest", description="'latest' or a model version number."
    )
    outside: OutsideRule = Field(
        "project",
        description="A start outside the canal enters it over a short blend (200, inside=false, "
        "projected=true), or is refused with 422 when 'raise'.",
    )
    goal: list[Coordinate] | None = Field(
        None, min_length=2, max_length=3,
        description="End the reproduction here: the canal is smoothly deformed so its end moves "
        "to the goal (the start region is untouched).",
    )
    persistence: Persistence = Field(
        "learned",
        description="How the start's offset from the canal's centre is carried: 'learned', "
        "what the demonstrations kept of their own start offsets, faded onto the canal's end; "
        "'constant', all of it until the end fades it (the paper's ratio rule); 'learned+end', "
        "for a start inside and no goal, kept to the end: the reproduction ends where the "
        "demonstrations' ends follow their starts (docs/method.md section 4b).",
    )
    duration: float | None = Field(
        None, gt=0, allow_inf_nan=False,
        description="Seconds: the times are stretched to end there (evenly paced along the path "
        "when the model has no time stamps).",
    )
    start_orientation: list[Coordinate] | None = Field(
        None, min_length=4, max_length=4, examples=[[0.0, 0.0, 0.0, 1.0]],
        description="Unit quaternion qx, qy, qz, qw of the start pose (used for every start of "
                    "a batch). Its offset from the canal's mean orientation is carried along; "
                    "a model without orientation ignores it and says so in 'notes'.")
    obstacles: list[ObstacleIn] | None = Field(
        None, max_length=MAX_OBSTACLES,
        description="Obstacles for this reproduction, added to the skill's scene (not stored).")
    route: int | None = Field(
        None, ge=0, le=options.MAX_ROUTES - 1,
        description="Follow this route's canal (0 .. routes-1 of the model); left out: the "
                    "route whose entry holds the start (docs/routes.md).")

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
    orientations: list[list[float]] | None = Field(
        None, description="(N', 4) unit quaternions qx, qy, qz, qw, one per position, when the "
                          "model has orientation; null otherwise.")
    goal: list[float] | None = None
    blocked: BlockedOut | None = Field(
        None, description="Set when obstacles close the canal: positions end before it.")
    scene_version: int | None = Field(
        None, description="The skill's scene version the reproduction went around (null: none).")
    obstacles: int = Field(0, description="How many obstacles it went around (scene + request).")
    start_clearance: float | None = Field(
        None, description="The start's distance to the nearest obstacle minus its clearance "
                          "(negative: inside it).")
    notes: list[str] = Field(
        default_factory=list,
        description="What the service did that the request did not say, e.g. "
                    "'model has no orientation: start_orientation ignored'.")
    route: int | None = Field(
        None, description="The route followed (0, 1, ...); null: the model's one canal.")
    approach: int = Field(
        0, description="Positions after the start on its straight approach to the path's "
                        "first point: when the start lies behind the canal's first plane "
                        "(taken in the demonstrations' first steps), or outside the canal "
                        "farther from that point than a demonstration stepped there (one "
                        "demonstrated step at a time); 0 for any other start.")
    route_reason: str | None = Field(
        None, description="Why that route: 'single' (one route), 'entry' (its entry holds the "
                          "start), 'nearest' (no entry holds it: the nearest entry), 'shared' "
                          "(several do: the nearest of those), "
                          "'forced' (the request's route).")
    ratios: list[float] = Field(
        default_factory=list,
        description="How far out each position is, as a share of the canal's reach in its "
                    "direction (0 on the directrix, 1 on the wall): the start's own ratio "
                    "(above 1 outside the canal), then each position in the plane of its "
                    "section. It shows how much of the start's offset the reproduction keeps, "
                    "section by section.")


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
