"""HTTP clients for the Canal service: :class:`CanalClient` (sync) and :class:`AsyncCanalClient`.

Both have the same methods (coroutines on the async one) and mirror the service's REST
resources::

    from canal_client import CanalClient

    with CanalClient("http://127.0.0.1:8000") as canal:
        canal.create_skill("pour", dim=3)
        for demo in demos:                       # numpy (T, 3) arrays or nested lists
            canal.add_demo("pour", demo)
        canal.upload_demo_file("pour", "run.mcap", topic="/ee_pose")
        canal.fit("pour", cross_section="ellipse")
        r = canal.reproduce("pour", [0.0, 0.02, 0.0])
        r.positions                              # (N, 3) numpy array

They return the contract's models (:mod:`canal_protocol.schemas`, numpy arrays where the
resource has arrays: :mod:`canal_client.resources`). Errors are :mod:`canal_client.errors`
exceptions carrying the service's message.

How it is built: :data:`ENDPOINTS` lists every exchange the client has with the service
(method, OpenAPI path, the protocol model sent and the one read back, query parameters);
tests diff it against the live service's ``/openapi.json``. Each method is described once, as
a generator of steps (an HTTP request, a streamed download, a local file read) that returns
the method's result (``_health``, ``_fit``, ...). The :class:`_operation` descriptor turns
that one description into a method of :class:`CanalClient` and a coroutine method of
:class:`AsyncCanalClient`; the two clients differ only in how they run a step.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import json
import os
import tempfile
from collections.abc import Callable, Coroutine, Generator, Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, BinaryIO, Generic, Literal, ParamSpec, TypeVar, overload
from urllib.parse import quote

import httpx
import numpy as np
from numpy.typing import ArrayLike
from pydantic import BaseModel, ValidationError

from canal_protocol.credentials import TOKEN_CHARACTERS, token_fault
from canal_protocol.options import (
    RECORDING_MAGIC,
    Alignment,
    CrossSection,
    Directrix,
    FrameKind,
    OutsideRule,
    Persistence,
    RecordingKind,
)
from canal_protocol.schemas import (
    CorrectedModel,
    CorrectionIn,
    CorrectionOut,
    CorrectionPath,
    DemonstrationIn,
    FitRequest,
    Page,
    ReproductionRequest,
    SceneIn,
    SceneOut,
    SkillCreate,
)

from .errors import (
    ArgumentError,
    CanalClientError,
    ConnectionFailedError,
    RequestTimeoutError,
    error_from_response,
)
from .resources import (
    DemoCreated,
    Demonstration,
    DemoSummary,
    FloatArray,
    Health,
    Model,
    ModelSummary,
    Reproduction,
    ReproductionBatch,
    Skill,
)

if TYPE_CHECKING:
    import canal_core

__all__ = [
    "DEFAULT_URL",
    "ENDPOINTS",
    "FILE_FORMATS",
    "AsyncCanalClient",
    "CanalClient",
    "Endpoint",
    "RecordingKind",
    "guess_format",
]

DEFAULT_URL = "http://127.0.0.1:8000"
Outside = OutsideRule
Version = int | Literal["latest"] | str
PAGE_SIZE = 1000

T = TypeVar("T")
M = TypeVar("M", bound=BaseModel)
P = ParamSpec("P")
_FILE_TYPES = {"csv": "text/csv", "npy": "application/x-npy", "mcap": "application/x-mcap"}
_SUFFIXES = {".csv": "csv", ".txt": "csv", ".npy": "npy", ".mcap": "mcap", ".json": "json"}


def _check(resp: httpx.Response) -> None:
    if not resp.is_success:
        raise error_from_response(resp.status_code, resp.content)


def _headers(token: str | None) -> dict[str, str]:
    headers = {"accept": "application/json"}
    if token:
        headers["authorization"] = f"Bearer {token}"
    return headers


# ---- the endpoints (diffed against the service's OpenAPI document in tests/protocol) --------


@dataclass(frozen=True)
class Endpoint:
    """One kind of exchange with the service, named as its OpenAPI document names it.

    ``path`` is the OpenAPI template (``/skills/{name}``); ``request`` the protocol model of
    the JSON body (``None``: no JSON body); ``response`` the model the answer is read as
    (``None``: no JSON answer); ``query`` the query parameters the client may send;
    ``status`` the success status.
    """

    method: str
    path: str
    request: type[BaseModel] | None = None
    response: type[BaseModel] | None = None
    query: tuple[str, ...] = ()
    status: int = 200
    #: The request's media type when it is not ``request``'s JSON (a multipart upload).
    media_type: str | None = None

    def url(self, **params: object) -> str:
        """``path`` with its ``{...}`` parameters filled in, each percent-encoded."""
        return self.path.format(**{k: _segment(k, v) for k, v in params.items()})


def _segment(key: str, value: object) -> str:
    """``value`` as one percent-encoded path segment. A '.' or '..' is encoded too: left as
    it is, the URL would drop it with the segment before (``/skills/../fit`` is ``/fit``),
    where the service refuses it as a skill name. An empty one is refused here: it would
    name another route (``/skills/`` redirects to the list)."""
    text = quote(str(value), safe="")
    if not text:
        what = "a skill name" if key == "name" else f"a {key}"
        raise ArgumentError("skill" if key == "name" else key, f"{what} that is not empty",
                            repr(value))
    return text.replace(".", "%2E") if text in (".", "..") else text


_PAGED = ("offset", "limit")
_MODEL = "/skills/{name}/models/{version}"

HEALTH = Endpoint("GET", "/healthz", response=Health)
CREATE_SKILL = Endpoint("POST", "/skills", SkillCreate, Skill, status=201)
LIST_SKILLS = Endpoint("GET", "/skills", response=Page[Skill], query=_PAGED)
GET_SKILL = Endpoint("GET", "/skills/{name}", response=Skill)
DELETE_SKILL = Endpoint("DELETE", "/skills/{name}", status=204)
ADD_DEMO = Endpoint("POST", "/skills/{name}/demonstrations", DemonstrationIn, DemoCreated,
                    query=("time_unit",), status=201)
# The same route, as a multipart file upload (its parameters travel in the query string).
UPLOAD_DEMO = Endpoint("POST", "/skills/{name}/demonstrations", None, DemoCreated,
                       query=("format", "topic", "label", "time_unit"), status=201,
                       media_type="multipart/form-data")
LIST_DEMOS = Endpoint("GET", "/skills/{name}/demonstrations", response=Page[DemoSummary],
                      query=_PAGED)
GET_DEMO = Endpoint("GET", "/skills/{name}/demonstrations/{id}", response=Demonstration)
DELETE_DEMO = Endpoint("DELETE", "/skills/{name}/demonstrations/{id}", status=204)
FIT = Endpoint("POST", "/skills/{name}/fit", FitRequest, ModelSummary, status=201)
LIST_MODELS = Endpoint("GET", "/skills/{name}/models", response=Page[ModelSummary],
                       query=_PAGED)
GET_MODEL = Endpoint("GET", _MODEL, response=Model, query=("serialized",))
GET_MESH = Endpoint("GET", _MODEL + "/mesh", query=("format", "n_angles", "caps", "envelope"))
REPRODUCE = Endpoint("POST", "/skills/{name}/reproductions", ReproductionRequest, Reproduction)
REPRODUCE_MANY = Endpoint("POST", "/skills/{name}/reproductions", ReproductionRequest,
                          ReproductionBatch)
GET_SCENE = Endpoint("GET", "/skills/{name}/scene", response=SceneOut)
PUT_SCENE = Endpoint("PUT", "/skills/{name}/scene", SceneIn, SceneOut)
DELETE_SCENE = Endpoint("DELETE", "/skills/{name}/scene", status=204)
CORRECT = Endpoint("POST", "/skills/{name}/corrections", CorrectionIn, CorrectedModel,
                   query=("time_unit",), status=201)
# A correction's path as a file (its other fields travel in the query string).
CORRECT_FILE = Endpoint("POST", "/skills/{name}/corrections/file", None, CorrectedModel,
                        query=("kind", "weight", "label", "model", "route", "format", "topic",
                               "time_unit"),
                        status=201, media_type="multipart/form-data")
LIST_CORRECTIONS = Endpoint("GET", "/skills/{name}/corrections", response=Page[CorrectionOut],
                            query=_PAGED)
GET_CORRECTION = Endpoint("GET", "/skills/{name}/corrections/{id}",
                         response=CorrectionPath)
UNDO_CORRECTION = Endpoint("DELETE", "/skills/{name}/corrections/{id}",
                           response=CorrectedModel)
RECORDING_RRD = Endpoint("GET", "/skills/{name}/recording.rrd")
RECORDING_MCAP = Endpoint("GET", "/skills/{name}/recording.mcap", query=("profile",))
REBUILD_RECORDING = Endpoint("POST", "/skills/{name}/recording/rebuild")

#: Every endpoint the client calls.
ENDPOINTS: dict[str, Endpoint] = {
    name: value for name, value in globals().items() if isinstance(value, Endpoint)
}
_RECORDINGS: dict[str, Endpoint] = {"rrd": RECORDING_RRD, "mcap": RECORDING_MCAP}


# ---- steps: what an operation asks its client to do ------------------------------------------


@dataclass(frozen=True)
class _Request(Generic[T]):
    """One HTTP exchange: what to send, and how to read a successful answer."""

    method: str
    path: str
    parse: Callable[[httpx.Response], T]
    params: dict[str, Any] | None = None
    body: bytes | None = None
    content_type: str | None = None
    files: dict[str, tuple[str, bytes, str]] | None = None

    def kwargs(self) -> dict[str, Any]:
        kw: dict[str, Any] = {}
        if self.params:
            kw["params"] = self.params
        if self.body is not None:
            kw["content"] = self.body
        if self.content_type is not None:
            kw["headers"] = {"content-type": self.content_type}
        if self.files is not None:
            kw["files"] = self.files
        return kw


@dataclass(frozen=True)
class _Download:
    """Stream a GET's answer into ``target`` (atomically); ``kind``: the recording it must
    be (checked on its first bytes), None for any file."""

    path: str
    params: dict[str, Any] | None
    target: Path
    kind: str | None = None


class _FileStart:
    """The first bytes of a download, checked against how its recording starts
    (:data:`~canal_protocol.options.RECORDING_MAGIC`) before the file is kept: a URL at
    another web app answers 200 too, with a page no viewer opens."""

    def __init__(self, step: _Download, resp: httpx.Response) -> None:
        self.kind = step.kind
        self.magic = b"" if step.kind is None else RECORDING_MAGIC[step.kind]
        self.resp = resp
        self.head = b""

    def feed(self, chunk: bytes) -> None:
        if len(self.head) < len(self.magic):
            self.head += chunk[:64]
            if len(self.head) >= len(self.magic):
                self.end()

    def end(self) -> None:
        """Raise :class:`CanalClientError` unless the answer starts as its recording does."""
        if self.head.startswith(self.magic):
            return
        got = self.resp.headers.get("content-type") or "no content type"
        raise CanalClientError(
            f"GET {self.resp.request.url.path}: the answer is not a Canal recording (expected "
            f"a .{self.kind} file, starting with {self.magic!r}; got {got}, "
            + (f"starting with {self.head[:24]!r})" if self.head else "empty)"))


@dataclass(frozen=True)
class _ReadFile:
    """The bytes of a local file (the async client reads it in a worker thread)."""

    path: Path


_Step = _Request[Any] | _Download | _ReadFile
_Steps = Generator[_Step, Any, T]


def _read(model: type[M]) -> Callable[[httpx.Response], M]:
    def parse(resp: httpx.Response) -> M:
        try:
            return model.model_validate_json(resp.content)
        except ValidationError as exc:
            raise CanalClientError(
                f"{resp.request.method} {resp.request.url.path}: the service's answer does not "
                f"match the contract ({model.__name__}): {exc}") from exc

    return parse


def _none(_resp: httpx.Response) -> None:
    return None


def _numpy_scalar(value: Any) -> Any:
    # Indices and options computed with numpy (np.int64 from argmin, np.float32) are plain
    # JSON numbers; a numpy boolean stays a boolean, which the service refuses for a number.
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"Object of type {type(value).__name__} is not JSON serializable")


def _json_body(obj: Any) -> bytes:
    # NaN/inf are sent as written so the service reports them with their field (httpx's own
    # encoder refuses them before anything is sent).
    return json.dumps(obj, allow_nan=True, separators=(",", ":"), default=_numpy_scalar).encode()


def _body(model: type[BaseModel], fields: dict[str, Any]) -> bytes:
    """The JSON body of ``model`` with the given fields (``None`` ones left out, so the
    service applies its defaults). The values are not validated here: the service does, and
    its error names the field."""
    unknown = set(fields) - set(model.model_fields)
    if unknown:  # a bug in this module, not in the caller's data
        raise TypeError(f"{model.__name__} has no field {sorted(unknown)}")
    return _json_body({k: v for k, v in fields.items() if v is not None})


def _request(endpoint: Endpoint, *, params: dict[str, Any] | None = None,
             body: dict[str, Any] | None = None, **path: object) -> _Request[Any]:
    parse: Callable[[httpx.Response], Any] = (
        _none if endpoint.response is None else _read(endpoint.response))
    if body is None:
        return _Request(endpoint.method, endpoint.url(**path), parse, params=params)
    assert endpoint.request is not None
    return _Request(endpoint.method, endpoint.url(**path), parse, params=params,
                    body=_body(endpoint.request, body), content_type="application/json")


def _all_pages(endpoint: Endpoint, **path: object) -> _Steps[list[Any]]:
    """Every item of a paged list, page after page."""
    assert endpoint.response is not None
    read, url = _read(endpoint.response), endpoint.url(**path)
    items: list[Any] = []
    while True:
        page = yield _Request("GET", url, read,
                              params={"offset": len(items), "limit": PAGE_SIZE})
        items.extend(page.items)
        if not page.items or len(items) >= page.total:
            return items


def shown_argument(value: Any, limit: int = 60) -> str:
    """An argument as a person wrote it, cut to ``limit`` characters: a string or a list in
    Python's spelling, anything else with its type's name."""
    text = repr(value) if isinstance(value, (str, list, tuple, int, float)) else (
        f"{type(value).__name__} {value!r}")
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _numbers(value: Any, name: str, expected: str) -> FloatArray:
    try:
        # numpy would cast complex numbers to real, dropping their imaginary parts with no
        # more than a warning
        complex_dtype = np.asarray(value).dtype if np.iscomplexobj(value) else None
        if complex_dtype is None:
            return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        # numpy names neither the argument nor what it holds ("could not convert string to
        # float", "inhomogeneous shape").
        raise ArgumentError(name, expected, shown_argument(value)) from None
    raise ArgumentError(name, "real numbers", f"complex numbers ({complex_dtype})")


def _rows(value: ArrayLike, name: str) -> list[Any]:
    rows = _numbers(value, name, "rows of numbers, each of one length")
    if rows.ndim != 2:
        raise ArgumentError(name, "a 2-D array of rows", f"shape {rows.shape}")
    return rows.tolist()  # type: ignore[no-any-return]


def _point(value: ArrayLike | None, name: str = "start") -> list[float] | None:
    if value is None:
        return None
    p = _numbers(value, name, "one point: a list of numbers")
    if p.ndim != 1:
        raise ArgumentError(name, "one point (D,)", f"shape {p.shape}")
    return p.tolist()  # type: ignore[no-any-return]


def _vector(value: ArrayLike | None, name: str) -> list[float] | None:
    return None if value is None else _numbers(value, name, "a list of numbers").ravel().tolist()


def _number(value: Any, name: str) -> float | None:
    if value is None:
        return None
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ArgumentError(name, "a number", shown_argument(value)) from None


def _model_ref(model: Version) -> int | str:
    if model == "latest":
        return model
    try:
        return int(model)
    except (TypeError, ValueError):
        raise ArgumentError("model", "'latest' or a version number", shown_argument(model)) from None


#: The demonstration file formats the clients send (JSON as a request body, the others as
#: an upload).
FILE_FORMATS: tuple[str, ...] = ("csv", "npy", "mcap", "json")


def guess_format(path: str | os.PathLike[str], format: str | None = None) -> str:
    """``csv``, ``npy``, ``mcap`` or ``json`` for a demonstration file: ``format`` when given,
    else from the file's suffix. Raises :class:`ArgumentError` for anything else."""
    if format is not None:
        fmt = str(format).lower()
        if fmt not in FILE_FORMATS:
            raise ArgumentError("format", "'csv', 'npy', 'mcap' or 'json'", shown_argument(format))
        return fmt
    fmt = _SUFFIXES.get(Path(path).suffix.lower(), "")
    if fmt not in FILE_FORMATS:
        raise ArgumentError("path", "a .csv, .npy, .mcap or .json file (or format=)",
                            shown_argument(Path(path).name))
    return fmt


def _json_file_body(path: Path, data: bytes, label: str | None) -> dict[str, Any]:
    try:
        doc = json.loads(data)
    except ValueError as exc:
        raise CanalClientError(f"{path.name}: not valid JSON: {exc}") from exc
    if isinstance(doc, list):
        doc = {"positions": doc}
    if not isinstance(doc, dict):
        raise CanalClientError(f"{path.name}: expected a JSON object with 'positions' "
                               f"or a list of rows")
    if label is not None:
        doc["label"] = label
    # Sent as it is, unknown keys too: the service names them in its 422.
    return doc


def _json_correction_file(path: Path, data: bytes) -> tuple[Any, Any]:
    """(samples, timestamps or None) of a JSON correction file: rows, an object with
    ``samples`` (and ``timestamps``), or a demonstration's own with ``positions``."""
    try:
        doc = json.loads(data)
    except ValueError as exc:
        raise CanalClientError(f"{path.name}: not valid JSON: {exc}") from exc
    if isinstance(doc, list):
        return doc, None
    key = next((k for k in ("samples", "positions") if isinstance(doc, dict) and k in doc), None)
    if key is None:
        got = (f"an object with {', '.join(map(repr, list(doc)[:5])) or 'no keys'}"
               if isinstance(doc, dict) else type(doc).__name__)
        raise CanalClientError(f"{path.name}: expected a list of rows or an object with "
                               f"'samples' (or a demonstration's 'positions'), got {got}")
    return doc[key], doc.get("timestamps")


# ---- the operations: each method of both clients, described once ----------------------------
# A generator of steps returning the method's result; its docstring is the method's.


def _health() -> _Steps[Health]:
    """``GET /healthz`` (never needs a token): status, database, recorder, bridge, version."""
    return (yield _request(HEALTH))


def _create_skill(name: str, dim: int = 3, description: str = "") -> _Steps[Skill]:
    """Create a skill; its dimension (2 or 3) is fixed for life. 409 if the name is taken."""
    return (yield _request(CREATE_SKILL, body={"name": name, "dim": dim,
                                               "description": description}))


def _list_skills() -> _Steps[list[Skill]]:
    """Every skill, by name (all pages)."""
    return (yield from _all_pages(LIST_SKILLS))


def _get_skill(name: str) -> _Steps[Skill]:
    """One skill with its counts and latest model version."""
    return (yield _request(GET_SKILL, name=name))


def _delete_skill(name: str) -> _Steps[None]:
    """Delete a skill with its demonstrations and models."""
    yield _request(DELETE_SKILL, name=name)


def _add_demo(skill: str, positions: ArrayLike, timestamps: ArrayLike | None = None,
              orientations: ArrayLike | None = None, label: str | None = None, *,
              time_unit: str | None = None) -> _Steps[DemoCreated]:
    """Add one demonstration: positions (T, D), optional timestamps (T,) and unit
    quaternions (T, 4) as qx, qy, qz, qw. Numpy arrays or nested lists. ``time_unit``
    (``"ms"``, ``"us"``, ``"ns"``; seconds by default) is the timestamps' unit."""
    params = None if time_unit is None else {"time_unit": time_unit}
    return (yield _request(ADD_DEMO, name=skill, params=params, body={
        "positions": _rows(positions, "positions"), "timestamps": _vector(timestamps, "timestamps"),
        "orientations": None if orientations is None else _rows(orientations, "orientations"),
        "label": label}))


def _upload_demo_file(skill: str, path: str | os.PathLike[str], *, format: str | None = None,
                      topic: str | None = None, label: str | None = None,
                      time_unit: str | None = None) -> _Steps[DemoCreated]:
    """Add one demonstration from a file: CSV, NPY or MCAP (``topic`` picks the pose
    topic) are uploaded as they are; a JSON file (``{"positions": ..., "timestamps"?, ...}``
    or a list of rows) is sent like :meth:`add_demo`. ``format`` overrides the suffix
    (the async client reads the file in a worker thread); ``time_unit`` (``"ms"``,
    ``"us"``, ``"ns"``; seconds by default) is the unit of its time column or timestamps
    (not for MCAP, whose message stamps are read as such)."""
    p = Path(path)
    fmt = guess_format(p, format)
    data: bytes = yield _ReadFile(p)
    if fmt == "json":
        doc = _json_file_body(p, data, label)
        return (yield _Request(ADD_DEMO.method, ADD_DEMO.url(name=skill), _read(DemoCreated),
                               params=None if time_unit is None else {"time_unit": time_unit},
                               body=_json_body(doc), content_type="application/json"))
    params = {k: v for k, v in (("format", fmt), ("topic", topic), ("label", label),
                                ("time_unit", time_unit)) if v is not None}
    return (yield _Request(UPLOAD_DEMO.method, UPLOAD_DEMO.url(name=skill), _read(DemoCreated),
                           params=params, files={"file": (p.name, data, _FILE_TYPES[fmt])}))


def _list_demos(skill: str) -> _Steps[list[DemoSummary]]:
    """Summaries (no arrays) of every demonstration of a skill, oldest first."""
    return (yield from _all_pages(LIST_DEMOS, name=skill))


def _get_demo(skill: str, id: int) -> _Steps[Demonstration]:
    """One demonstration with its arrays as numpy."""
    return (yield _request(GET_DEMO, name=skill, id=int(id)))


def _delete_demo(skill: str, id: int) -> _Steps[None]:
    """Delete one demonstration (model versions keep the ids they used)."""
    yield _request(DELETE_DEMO, name=skill, id=int(id))


def _fit(skill: str, *, cross_section: CrossSection | None = None,
         frames: FrameKind | None = None, alignment: Alignment | None = None,
         directrix: Directrix | None = None, n_samples: int | None = None,
         frame_smoothing: float | None = None, by_time: bool | None = None,
         demo_ids: Iterable[int] | None = None, orientation: bool | None = None,
         keep_corrections: bool | None = None, routes: int | None = None,
         route_separation: float | None = None) -> _Steps[ModelSummary]:
    """Fit a new model version; options left ``None`` take the service's defaults, which
    are canal_core's (:class:`canal_protocol.schemas.FitRequest` lists them). The skill's
    corrections are re-applied to the new canal unless ``keep_corrections=False``.
    Demonstrations that go clearly different ways become routes, one canal each
    (``routes=1``: one canal of all; ``routes=N``: exactly N); the answer's ``routes`` and
    ``demo_routes`` say how they were split."""
    return (yield _request(FIT, name=skill, body={
        "cross_section": cross_section, "frames": frames, "alignment": alignment,
        "directrix": directrix, "n_samples": n_samples, "frame_smoothing": frame_smoothing,
        "by_time": by_time, "demo_ids": None if demo_ids is None else [int(i) for i in demo_ids],
        "orientation": orientation, "keep_corrections": keep_corrections, "routes": routes,
        "route_separation": route_separation}))


def _correct(skill: str, samples: ArrayLike, kind: Literal["include", "exclude"] = "include", *,
             model: Version = "latest", weight: float = 1.0, label: str = "",
             timestamps: ArrayLike | None = None, route: int | None = None,
             time_unit: str | None = None) -> _Steps[CorrectedModel]:
    """Refine the skill's canal by a correction, a path (M, D) over part of it: ``include``
    (this path is right too: the canal grows locally to hold it, the centre moves towards it
    by ``weight`` demonstrations) or ``exclude`` (the robot was pushed away from where it
    went: the canal narrows on that side). Answers the new latest model version with the
    stored correction (its ``id`` undoes it). A model of several routes: ``route`` names the
    route corrected (None: every route the samples pass through). ``time_unit`` (``"ms"``,
    ``"us"``, ``"ns"``; seconds by default) is the timestamps' unit."""
    params = None if time_unit is None else {"time_unit": time_unit}
    return (yield _request(CORRECT, name=skill, params=params, body={
        "kind": kind, "samples": _rows(samples, "samples"), "model": _model_ref(model),
        "weight": float(weight), "label": label, "route": route,
        "timestamps": _vector(timestamps, "timestamps")}))


def _correct_file(skill: str, path: str | os.PathLike[str],
                  kind: Literal["include", "exclude"] = "include", *, model: Version = "latest",
                  weight: float = 1.0, label: str | None = None, route: int | None = None,
                  format: str | None = None, topic: str | None = None,
                  time_unit: str | None = None) -> _Steps[CorrectedModel]:
    """:meth:`correct` by a path recorded in a file: CSV, NPY or MCAP (``topic`` picks the pose
    topic) are uploaded as they are and read as a demonstration file is (the label defaults
    to the file's name); a JSON file (rows, ``{"samples": rows, "timestamps"?: ...}`` or a
    demonstration's ``{"positions": rows, ...}``) is read here and sent as :meth:`correct`
    sends it."""
    p = Path(path)
    fmt = guess_format(p, format)
    data: bytes = yield _ReadFile(p)
    if fmt == "json":
        rows, times = _json_correction_file(p, data)
        return (yield from _correct(skill, rows, kind, model=model, weight=weight,
                                    label=p.name if label is None else label, route=route,
                                    timestamps=times, time_unit=time_unit))
    params = {k: v for k, v in (("kind", kind), ("weight", _number(weight, "weight")),
                                ("label", label), ("model", _model_ref(model)),
                                ("route", route), ("format", fmt), ("topic", topic),
                                ("time_unit", time_unit))
              if v is not None}
    return (yield _Request(CORRECT_FILE.method, CORRECT_FILE.url(name=skill),
                           _read(CorrectedModel), params=params,
                           files={"file": (p.name, data, _FILE_TYPES[fmt])}))


def _list_corrections(skill: str) -> _Steps[list[CorrectionOut]]:
    """The skill's corrections, oldest first (undone ones say so)."""
    return (yield from _all_pages(LIST_CORRECTIONS, name=skill))


def _get_correction(skill: str, id: int) -> _Steps[CorrectionPath]:
    """Correction ``id`` with its path as it was sent (model versions name it by id)."""
    return (yield _request(GET_CORRECTION, name=skill, id=int(id)))


def _undo_correction(skill: str, id: int) -> _Steps[CorrectedModel]:
    """A new latest model version without correction ``id`` (the others re-applied)."""
    return (yield _request(UNDO_CORRECTION, name=skill, id=int(id)))


def _list_models(skill: str) -> _Steps[list[ModelSummary]]:
    """Every model version of a skill, newest first."""
    return (yield from _all_pages(LIST_MODELS, name=skill))


def _get_model(skill: str, version: Version = "latest", serialized: bool = False
               ) -> _Steps[Model]:
    """A model version's geometry (with the canal_core dict when ``serialized``)."""
    return (yield _request(GET_MODEL, name=skill, version=version,
                           params={"serialized": "true"} if serialized else None))


def _get_canal(skill: str, version: Version = "latest") -> _Steps[canal_core.Canal]:
    """A model version as a local ``canal_core.Canal`` (reproduce, contains, tracker); a
    model of several routes answers its canal of all the demonstrations (:meth:`get_routes`
    has every route's)."""
    routes = yield from _get_routes(skill, version)
    return routes.pooled


def _get_routes(skill: str, version: Version = "latest") -> _Steps[canal_core.Routes]:
    """A model version as a local ``canal_core.Routes`` (one route for a single canal):
    ``choose(start)``, ``canal_for(choice)``, ``reproduce_detailed(start)``."""
    import canal_core

    model: Model = yield _request(GET_MODEL, name=skill, version=version,
                                  params={"serialized": "true"})
    if not isinstance(model.serialized, dict):
        raise CanalClientError("the service did not send the serialized model")
    return canal_core.routes.routes_from_dict(model.serialized)


def _mesh(skill: str, version: Version = "latest", format: str = "ply",
          n_angles: int | None = None, caps: bool | None = None,
          envelope: bool | None = None) -> _Steps[bytes]:
    """The canal surface as ``ply``, ``obj``, ``glb`` or ``json`` bytes."""
    params: dict[str, Any] = {"format": format}
    if n_angles is not None:
        params["n_angles"] = n_angles
    if caps is not None:
        params["caps"] = str(caps).lower()
    if envelope is not None:
        params["envelope"] = str(envelope).lower()
    return (yield _Request(GET_MESH.method, GET_MESH.url(name=skill, version=version),
                           lambda resp: resp.content, params=params))


def _obstacles(value: Iterable[Any] | None) -> list[dict[str, Any]] | None:
    """Obstacles as the service takes them: dicts (``{"kind": "sphere", "center": [...],
    "radius": r}``, see :class:`canal_protocol.schemas.ObstacleIn`), or anything with
    ``to_dict()`` (:class:`canal_core.obstacles.Obstacle`), or a ``Scene``."""
    if value is None:
        return None
    if hasattr(value, "to_list"):
        items = value.to_list()
    elif isinstance(value, Iterable) and not isinstance(value, (Mapping, str, bytes)):
        items = list(value)
    else:
        raise ArgumentError("obstacles", "a list of obstacles", shown_argument(value))
    obstacles = []
    for i, o in enumerate(items):
        if hasattr(o, "to_dict"):
            obstacles.append(o.to_dict())
        elif isinstance(o, Mapping):
            obstacles.append(dict(o))
        else:
            raise ArgumentError(f"obstacles[{i}]", "an obstacle: a dict such as "
                                "{'kind': 'sphere', 'center': [x, y, z], 'radius': r}",
                                shown_argument(o))
    return obstacles


def _get_scene(skill: str) -> _Steps[SceneOut]:
    """The skill's scene (``version`` 0 and no obstacles when none was set)."""
    return (yield _request(GET_SCENE, name=skill))


def _set_scene(skill: str, obstacles: Iterable[Any]) -> _Steps[SceneOut]:
    """Replace the skill's scene: every later reproduction, and every live stream from its
    next pose, goes around these obstacles. The answer carries the new ``version``."""
    return (yield _request(PUT_SCENE, name=skill, body={"obstacles": _obstacles(obstacles)}))


def _clear_scene(skill: str) -> _Steps[None]:
    """Remove every obstacle from the skill's scene (a new, empty version)."""
    return (yield _request(DELETE_SCENE, name=skill))


def _reproduce(skill: str, start: ArrayLike, *, model: Version = "latest",
               outside: Outside = "project", goal: ArrayLike | None = None,
               duration: float | None = None, start_orientation: ArrayLike | None = None,
               obstacles: Iterable[Any] | None = None, route: int | None = None,
               persistence: Persistence = "learned"
               ) -> _Steps[Reproduction]:
    """Reproduce from ``start`` (D,). A start outside the canal enters it over a short blend
    (``outside="project"``) or is refused with :class:`~canal_client.errors.OutsideCanalError`
    (``outside="raise"``). ``goal`` (D,) deforms the canal to end there; ``duration``
    (seconds) stretches the returned ``times``. ``start_orientation`` (4,) qx, qy, qz, qw:
    the start pose's orientation, carried along when the model has orientation
    (``result.orientations``); a model without it ignores it and says so in
    ``result.notes``. ``obstacles`` are added to the skill's scene for this reproduction
    (``result.blocked`` says where they close the canal). A model of several routes follows
    the route whose entry holds the start (``result.route``, ``result.route_reason``), or
    ``route`` when given. A start behind the canal's first plane, or outside it and farther
    from the path than a demonstration stepped, reaches the path along a straight line in
    ``result.approach`` positions. ``persistence``: how the start's
    offset is carried ("learned", "constant", or "learned+end" to end where the
    demonstrations' ends follow their starts; docs/method.md section 4b)."""
    return (yield _request(REPRODUCE, name=skill, body={
        "start": _point(start), "model": _model_ref(model), "outside": outside,
        "goal": _point(goal, "goal"), "duration": _number(duration, "duration"),
        "start_orientation": _point(start_orientation, "start_orientation"),
        "obstacles": _obstacles(obstacles), "route": route, "persistence": persistence}))


def _reproduce_many(skill: str, starts: ArrayLike, *, model: Version = "latest",
                    outside: Outside = "project", goal: ArrayLike | None = None,
                    duration: float | None = None, start_orientation: ArrayLike | None = None,
                    obstacles: Iterable[Any] | None = None, route: int | None = None,
                    persistence: Persistence = "learned"
                    ) -> _Steps[list[Reproduction]]:
    """Reproduce from each start (at most 1000) in one request, in order
    (``start_orientation``, ``obstacles``, ``route`` and ``persistence`` are used for every
    start)."""
    batch: ReproductionBatch = yield _request(REPRODUCE_MANY, name=skill, body={
        "starts": _rows(starts, "starts"), "model": _model_ref(model), "outside": outside,
        "goal": _point(goal, "goal"), "duration": _number(duration, "duration"),
        "start_orientation": _point(start_orientation, "start_orientation"),
        "obstacles": _obstacles(obstacles), "route": route, "persistence": persistence})
    return batch.reproductions


def _download_recording(skill: str, kind: RecordingKind, path: str | os.PathLike[str], *,
                        profile: str | None = None) -> _Steps[Path]:
    """Stream the skill's ``.rrd`` or ``.mcap`` snapshot to ``path`` (written to a temporary
    file beside it, then renamed: ``path`` is either the whole file or untouched).
    ``profile="ros2"`` (mcap only): a rosbag2-compatible CDR file instead of Foxglove JSON."""
    endpoint = _RECORDINGS.get(kind)
    if endpoint is None:
        raise ArgumentError("kind", "'rrd' or 'mcap'", shown_argument(kind))
    target = Path(path)
    yield _Download(endpoint.url(name=skill), None if profile is None else {"profile": profile},
                    target, kind)
    return target


def _rebuild_recording(skill: str) -> _Steps[dict[str, Any]]:
    """Regenerate the skill's recordings from the service's database (demonstrations and
    model versions); answers what was written (``demos``, ``models``)."""
    return (yield _Request(REBUILD_RECORDING.method, REBUILD_RECORDING.url(name=skill),
                           lambda resp: dict(resp.json())))


class _operation(Generic[P, T]):
    """One operation, bound as a method of either client: a plain method on
    :class:`CanalClient`, a coroutine method on :class:`AsyncCanalClient`."""

    def __init__(self, steps: Callable[P, _Steps[T]]) -> None:
        self.steps = steps
        self.__doc__ = steps.__doc__
        self.name = steps.__name__.lstrip("_")

    def __set_name__(self, owner: type[Any], name: str) -> None:
        self.name = name

    @overload
    def __get__(self, client: None, owner: type[Any]) -> _operation[P, T]: ...

    @overload
    def __get__(self, client: CanalClient, owner: type[Any]) -> Callable[P, T]: ...

    @overload
    def __get__(self, client: AsyncCanalClient, owner: type[Any]
                ) -> Callable[P, Coroutine[Any, Any, T]]: ...

    def __get__(self, client: CanalClient | AsyncCanalClient | None, owner: type[Any]) -> Any:
        if client is None:
            return self
        return client._bind(self.name, self.steps)


class _Operations:
    """The methods both clients have, each from its one description above."""

    health = _operation(_health)
    create_skill = _operation(_create_skill)
    list_skills = _operation(_list_skills)
    get_skill = _operation(_get_skill)
    delete_skill = _operation(_delete_skill)
    add_demo = _operation(_add_demo)
    upload_demo_file = _operation(_upload_demo_file)
    list_demos = _operation(_list_demos)
    get_demo = _operation(_get_demo)
    delete_demo = _operation(_delete_demo)
    fit = _operation(_fit)
    list_models = _operation(_list_models)
    get_model = _operation(_get_model)
    get_canal = _operation(_get_canal)
    get_routes = _operation(_get_routes)
    mesh = _operation(_mesh)
    reproduce = _operation(_reproduce)
    reproduce_many = _operation(_reproduce_many)
    get_scene = _operation(_get_scene)
    set_scene = _operation(_set_scene)
    clear_scene = _operation(_clear_scene)
    correct = _operation(_correct)
    correct_file = _operation(_correct_file)
    list_corrections = _operation(_list_corrections)
    get_correction = _operation(_get_correction)
    undo_correction = _operation(_undo_correction)
    download_recording = _operation(_download_recording)
    rebuild_recording = _operation(_rebuild_recording)


@contextlib.contextmanager
def _atomic_file(path: Path) -> Iterator[BinaryIO]:
    """A temporary file beside ``path``, renamed onto it when the block ends without error
    (removed otherwise): ``path`` is either the whole new file or untouched."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent)
    tmp = Path(name)
    try:
        with os.fdopen(fd, "wb") as out:
            yield out
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


# ---- the clients: they differ only in how they run a step ------------------------------------


class _Base(_Operations):
    """Settings shared by both clients."""

    def __init__(self, url: str, token: str | None,
                 timeout: float | httpx.Timeout | None) -> None:
        fault = None if not token else token_fault(token)
        if fault is not None:  # httpx would fail at the first request, naming no argument
            raise ArgumentError("token", TOKEN_CHARACTERS, fault)
        self.url = url.rstrip("/")
        self.token = token
        self.timeout = timeout

    def _transport_error(self, exc: httpx.TransportError) -> CanalClientError:
        timeout = self.timeout.read if isinstance(self.timeout, httpx.Timeout) else self.timeout
        if isinstance(exc, httpx.TimeoutException) and not isinstance(exc, httpx.ConnectTimeout):
            return RequestTimeoutError(self.url, timeout)
        return ConnectionFailedError(self.url, str(exc) or type(exc).__name__)


class CanalClient(_Base):
    """Synchronous client of the Canal service.

    Args:
        url: the service's base URL.
        token: sent as ``Authorization: Bearer TOKEN`` when given.
        timeout: seconds per request (``httpx.Timeout`` for finer control); fits of large
            skills can take a while.
        transport: an ``httpx.BaseTransport`` (e.g. ``httpx.MockTransport`` in tests).

    Use as a context manager, or call :meth:`close`. Its methods are those of
    :class:`_Operations` (health, skills, demonstrations, models, reproductions, recordings).
    """

    def __init__(self, url: str = DEFAULT_URL, token: str | None = None,
                 timeout: float | httpx.Timeout | None = 30.0,
                 transport: httpx.BaseTransport | None = None) -> None:
        super().__init__(url, token, timeout)
        self._http = httpx.Client(base_url=self.url, headers=_headers(token), timeout=timeout,
                                  transport=transport)

    def __enter__(self) -> CanalClient:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def close(self) -> None:
        """Close the connection pool."""
        self._http.close()

    def _bind(self, name: str, steps: Callable[P, _Steps[T]]) -> Callable[P, T]:
        @functools.wraps(steps)
        def method(*args: P.args, **kwargs: P.kwargs) -> T:
            return self._drive(steps(*args, **kwargs))

        method.__name__ = name
        method.__qualname__ = f"{type(self).__name__}.{name}"
        return method

    def _drive(self, steps: _Steps[T]) -> T:
        try:
            step = next(steps)
            while True:
                step = steps.send(self._run(step))
        except StopIteration as stop:
            return stop.value  # type: ignore[no-any-return]

    def _run(self, step: _Step) -> Any:
        if isinstance(step, _ReadFile):
            return step.path.read_bytes()
        if isinstance(step, _Download):
            return self._download(step)
        return self._call(step)

    def _call(self, req: _Request[T]) -> T:
        try:
            resp = self._http.request(req.method, req.path, **req.kwargs())
        except httpx.TransportError as exc:
            raise self._transport_error(exc) from exc
        _check(resp)
        return req.parse(resp)

    def _download(self, step: _Download) -> None:
        with _atomic_file(step.target) as out:
            try:
                with self._http.stream("GET", step.path, params=step.params) as resp:
                    if not resp.is_success:
                        resp.read()
                        _check(resp)
                    start = _FileStart(step, resp)
                    for chunk in resp.iter_bytes(1 << 16):
                        start.feed(chunk)
                        out.write(chunk)
                    start.end()
            except httpx.TransportError as exc:
                raise self._transport_error(exc) from exc


class AsyncCanalClient(_Base):
    """Asynchronous client of the Canal service: the methods of :class:`CanalClient`, as
    coroutines. Use with ``async with``, or ``await client.aclose()``."""

    def __init__(self, url: str = DEFAULT_URL, token: str | None = None,
                 timeout: float | httpx.Timeout | None = 30.0,
                 transport: httpx.AsyncBaseTransport | None = None) -> None:
        super().__init__(url, token, timeout)
        self._http = httpx.AsyncClient(base_url=self.url, headers=_headers(token),
                                       timeout=timeout, transport=transport)

    async def __aenter__(self) -> AsyncCanalClient:
        return self

    async def __aexit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                        tb: TracebackType | None) -> None:
        await self.aclose()

    async def aclose(self) -> None:
        """Close the connection pool."""
        await self._http.aclose()

    close = aclose

    def _bind(self, name: str, steps: Callable[P, _Steps[T]]
              ) -> Callable[P, Coroutine[Any, Any, T]]:
        @functools.wraps(steps)
        async def method(*args: P.args, **kwargs: P.kwargs) -> T:
            return await self._drive(steps(*args, **kwargs))

        method.__name__ = name
        method.__qualname__ = f"{type(self).__name__}.{name}"
        return method

    async def _drive(self, steps: _Steps[T]) -> T:
        try:
            step = next(steps)
            while True:
                step = steps.send(await self._run(step))
        except StopIteration as stop:
            return stop.value  # type: ignore[no-any-return]

    async def _run(self, step: _Step) -> Any:
        if isinstance(step, _ReadFile):
            return await asyncio.to_thread(step.path.read_bytes)
        if isinstance(step, _Download):
            return await self._download(step)
        return await self._call(step)

    async def _call(self, req: _Request[T]) -> T:
        try:
            resp = await self._http.request(req.method, req.path, **req.kwargs())
        except httpx.TransportError as exc:
            raise self._transport_error(exc) from exc
        _check(resp)
        return req.parse(resp)

    async def _download(self, step: _Download) -> None:
        with _atomic_file(step.target) as out:
            try:
                async with self._http.stream("GET", step.path, params=step.params) as resp:
                    if not resp.is_success:
                        await resp.aread()
                        _check(resp)
                    start = _FileStart(step, resp)
                    async for chunk in resp.aiter_bytes(1 << 16):
                        start.feed(chunk)
                        out.write(chunk)
                    start.end()
            except httpx.TransportError as exc:
                raise self._transport_error(exc) from exc
