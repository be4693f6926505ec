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

Errors are :mod:`canal_client.errors` exceptions carrying the service's message.

How it is built: each method describes its HTTP exchange as a :class:`_Request` (method, path,
body, and the function that turns the answer into the return value), made by the module-level
``_*`` builders shared by both clients; the clients only send it (``_call``). Paged lists are
generators of requests (:func:`_all_pages`) driven by either client.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import tempfile
from collections.abc import Callable, Generator, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, BinaryIO, Generic, Literal, TypeVar
from urllib.parse import quote

import httpx
import numpy as np
from numpy.typing import ArrayLike

from .errors import (
    CanalClientError,
    ConnectionFailedError,
    RequestTimeoutError,
    error_from_response,
)
from .resources import (
    DemoCreated,
    Demonstration,
    DemoSummary,
    Health,
    Model,
    ModelSummary,
    Reproduction,
    Skill,
)

if TYPE_CHECKING:
    import canal_core

__all__ = ["DEFAULT_URL", "AsyncCanalClient", "CanalClient", "RecordingKind", "guess_format"]

DEFAULT_URL = "http://127.0.0.1:8000"
RecordingKind = Literal["rrd", "mcap"]
Version = int | Literal["latest"] | str
PAGE_SIZE = 1000

T = TypeVar("T")
_FILE_TYPES = {"csv": "text/csv", "npy": "application/x-npy", "mcap": "application/x-mcap"}
_SUFFIXES = {".csv": "csv", ".txt": "csv", ".npy": "npy", ".mcap": "mcap", ".json": "json"}


# ---- request descriptions (shared by both clients) -------------------------------------------


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


def _json_body(obj: Any) -> bytes:
    # NaN/inf are sent as written so the service reports them with their field (httpx's own
    # encoder refuses them before anything is sent).
    return json.dumps(obj, allow_nan=True, separators=(",", ":")).encode()


def _seg(value: object) -> str:
    return quote(str(value), safe="")


def _skill_path(skill: str, *rest: object) -> str:
    return "/".join(["/skills", _seg(skill), *(_seg(r) for r in rest)])


def _json_of(parse: Callable[[dict[str, Any]], T]) -> Callable[[httpx.Response], T]:
    return lambda resp: parse(resp.json())


def _none(_resp: httpx.Response) -> None:
    return None


def _rows(value: ArrayLike, name: str) -> list[Any]:
    rows = np.asarray(value, dtype=np.float64)
    if rows.ndim != 2:
        raise ValueError(f"{name}: expected a 2-D array of rows, got shape {rows.shape}")
    return rows.tolist()  # type: ignore[no-any-return]


def _point(value: ArrayLike, name: str = "start") -> list[float]:
    p = np.asarray(value, dtype=np.float64)
    if p.ndim != 1:
        raise ValueError(f"{name}: expected one point (D,), got shape {p.shape}")
    return p.tolist()  # type: ignore[no-any-return]


def _post_json(path: str, payload: Any, parse: Callable[[httpx.Response], T],
               params: dict[str, Any] | None = None) -> _Request[T]:
    return _Request("POST", path, parse, params=params, body=_json_body(payload),
                    content_type="application/json")


def _health() -> _Request[Health]:
    return _Request("GET", "/healthz", _json_of(Health.from_json))


def _create_skill(name: str, dim: int, description: str) -> _Request[Skill]:
    return _post_json("/skills", {"name": name, "dim": dim, "description": description},
                      _json_of(Skill.from_json))


def _get_skill(name: str) -> _Request[Skill]:
    return _Request("GET", _skill_path(name), _json_of(Skill.from_json))


def _get_demo(skill: str, id: int) -> _Request[Demonstration]:
    return _Request("GET", _skill_path(skill, "demonstrations", int(id)),
                    _json_of(Demonstration.from_json))


def _delete(path: str) -> _Request[None]:
    return _Request("DELETE", path, _none)


def _demo_payload(positions: ArrayLike, timestamps: ArrayLike | None,
                  orientations: ArrayLike | None, label: str | None) -> dict[str, Any]:
    payload: dict[str, Any] = {"positions": _rows(positions, "positions")}
    if timestamps is not None:
        payload["timestamps"] = np.asarray(timestamps, dtype=np.float64).ravel().tolist()
    if orientations is not None:
        payload["orientations"] = _rows(orientations, "orientations")
    if label is not None:
        payload["label"] = label
    return payload


def _add_demo(skill: str, payload: dict[str, Any]) -> _Request[DemoCreated]:
    return _post_json(_skill_path(skill, "demonstrations"), payload,
                      _json_of(DemoCreated.from_json))


def guess_format(path: str | os.PathLike[str], format: str | None = None) -> str:
    """``csv``, ``npy``, ``mcap`` or ``json`` for a demonstration file: ``format`` when given,
    else from the file's suffix. Raises ``ValueError`` for anything else."""
    fmt = (format or _SUFFIXES.get(Path(path).suffix.lower(), "")).lower()
    if fmt not in ("csv", "npy", "mcap", "json"):
        raise ValueError(f"{Path(path).name}: unsupported demonstration file type "
                         f"(expected .csv, .npy, .mcap or .json, or pass format=)")
    return fmt


def _upload(skill: str, path: Path, data: bytes, format: str | None, topic: str | None,
            label: str | None) -> _Request[DemoCreated]:
    fmt = guess_format(path, format)
    if fmt == "json":
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
        return _add_demo(skill, doc)
    params = {k: v for k, v in (("format", fmt), ("topic", topic), ("label", label))
              if v is not None}
    return _Request("POST", _skill_path(skill, "demonstrations"),
                    _json_of(DemoCreated.from_json), params=params,
                    files={"file": (path.name, data, _FILE_TYPES[fmt])})


def _page(path: str, offset: int, parse: Callable[[dict[str, Any]], T]
          ) -> _Request[tuple[list[T], int]]:
    def read(resp: httpx.Response) -> tuple[list[T], int]:
        d = resp.json()
        return [parse(item) for item in d["items"]], int(d["total"])

    return _Request("GET", path, read, params={"offset": offset, "limit": PAGE_SIZE})


_Pages = Generator[_Request[tuple[list[T], int]], tuple[list[T], int], list[T]]


def _all_pages(path: str, parse: Callable[[dict[str, Any]], T]) -> _Pages[T]:
    """Every item of a paged list: yields page requests, is sent their answers."""
    items: list[T] = []
    while True:
        page, total = yield _page(path, len(items), parse)
        items.extend(page)
        if not page or len(items) >= total:
            return items


def _version(version: Version) -> str:
    return str(version)


def _fit(skill: str, options: dict[str, Any]) -> _Request[ModelSummary]:
    payload = {k: v for k, v in options.items() if v is not None}
    if "demo_ids" in payload:
        payload["demo_ids"] = [int(i) for i in payload["demo_ids"]]
    return _post_json(_skill_path(skill, "fit"), payload, _json_of(ModelSummary.from_json))


def _get_model(skill: str, version: Version, serialized: bool) -> _Request[Model]:
    params = {"serialized": "true"} if serialized else None
    return _Request("GET", _skill_path(skill, "models", _version(version)),
                    _json_of(Model.from_json), params=params)


def _canal_from(resp: httpx.Response) -> canal_core.Canal:
    import canal_core

    serialized = resp.json().get("serialized")
    if not isinstance(serialized, dict):
        raise CanalClientError("the service did not send the serialized model")
    return canal_core.Canal.from_dict(serialized)


def _get_canal(skill: str, version: Version) -> _Request[canal_core.Canal]:
    return _Request("GET", _skill_path(skill, "models", _version(version)), _canal_from,
                    params={"serialized": "true"})


def _mesh(skill: str, version: Version, format: str, n_angles: int | None,
          caps: bool | None, envelope: bool | None) -> _Request[bytes]:
    params: dict[str, Any] = {"format": format}
    if n_angles is not None:
        params["n_angles"] = n_angles
    if caps is not None:
        params["caps"] = str(caps).lower()
    if envelope is not None:
        params["envelope"] = str(envelope).lower()
    return _Request("GET", _skill_path(skill, "models", _version(version), "mesh"),
                    lambda resp: resp.content, params=params)


def _model_ref(model: Version) -> int | str:
    return model if model == "latest" else int(model)


def _reproduction_options(goal: ArrayLike | None, duration: float | None,
                          start_orientation: ArrayLike | None) -> dict[str, Any]:
    """The optional request fields that were given (absent ones are not sent)."""
    out: dict[str, Any] = {}
    if goal is not None:
        out["goal"] = _point(goal, "goal")
    if duration is not None:
        out["duration"] = float(duration)
    if start_orientation is not None:
        out["start_orientation"] = _point(start_orientation, "start_orientation")
    return out


def _reproduce(skill: str, start: ArrayLike, model: Version, outside: str,
               goal: ArrayLike | None = None, duration: float | None = None,
               start_orientation: ArrayLike | None = None) -> _Request[Reproduction]:
    return _post_json(_skill_path(skill, "reproductions"),
                      {"start": _point(start), "model": _model_ref(model), "outside": outside,
                       **_reproduction_options(goal, duration, start_orientation)},
                      _json_of(Reproduction.from_json))


def _reproduce_many(skill: str, starts: ArrayLike, model: Version, outside: str,
                    goal: ArrayLike | None = None, duration: float | None = None,
                    start_orientation: ArrayLike | None = None) -> _Request[list[Reproduction]]:
    def read(resp: httpx.Response) -> list[Reproduction]:
        return [Reproduction.from_json(r) for r in resp.json()["reproductions"]]

    return _post_json(_skill_path(skill, "reproductions"),
                      {"starts": _rows(starts, "starts"), "model": _model_ref(model),
                       "outside": outside, **_reproduction_options(goal, duration, start_orientation)},
                      read)


def _rebuild_recording(skill: str) -> _Request[dict[str, Any]]:
    return _Request("POST", _skill_path(skill, "recording", "rebuild"), _json_of(dict))


def _recording_path(skill: str, kind: str) -> str:
    if kind not in ("rrd", "mcap"):
        raise ValueError(f"kind: expected 'rrd' or 'mcap', got {kind!r}")
    return _skill_path(skill, f"recording.{kind}")


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


def _timeout_of(timeout: float | httpx.Timeout | None) -> float | None:
    return timeout.read if isinstance(timeout, httpx.Timeout) else timeout


def _transport_error(url: str, timeout: float | None, exc: httpx.TransportError
                     ) -> CanalClientError:
    if isinstance(exc, httpx.TimeoutException) and not isinstance(exc, httpx.ConnectTimeout):
        return RequestTimeoutError(url, timeout)
    return ConnectionFailedError(url, str(exc) or type(exc).__name__)


def _check(resp: httpx.Response) -> None:
    if not resp.is_success:
        raise error_from_response(resp.status_code, resp.content)


def _headers(token: str | None) -> dict[str, str]:
    headers = {"accept": "application/json"}
    if token:
        headers["authorization"] = f"Bearer {token}"
    return headers


# ---- the clients -----------------------------------------------------------------------------


class _Base:
    """Settings shared by both clients."""

    def __init__(self, url: str, token: str | None,
                 timeout: float | httpx.Timeout | None) -> None:
        self.url = url.rstrip("/")
        self.token = token
        self.timeout = timeout


class CanalClient(_Base):
    """Synchronous client of the Canal service.

    Args:
        url: the service's base URL.
        token: sent as ``Authorization: Bearer TOKEN`` when given.
        timeout: seconds per request (``httpx.Timeout`` for finer control); fits of large
            skills can take a while.
        transport: an ``httpx.BaseTransport`` (e.g. ``httpx.MockTransport`` in tests).

    Use as a context manager, or call :meth:`close`.
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

    def _call(self, req: _Request[T]) -> T:
        try:
            resp = self._http.request(req.method, req.path, **req.kwargs())
        except httpx.TransportError as exc:
            raise _transport_error(self.url, _timeout_of(self.timeout), exc) from exc
        _check(resp)
        return req.parse(resp)

    def _drive(self, steps: Generator[_Request[Any], Any, T]) -> T:
        try:
            req = next(steps)
            while True:
                req = steps.send(self._call(req))
        except StopIteration as stop:
            return stop.value  # type: ignore[no-any-return]

    # -- health and skills --

    def health(self) -> Health:
        """``GET /healthz`` (never needs a token)."""
        return self._call(_health())

    def create_skill(self, name: str, dim: int = 3, description: str = "") -> Skill:
        """Create a skill; its dimension (2 or 3) is fixed for life. 409 if the name is taken."""
        return self._call(_create_skill(name, dim, description))

    def list_skills(self) -> list[Skill]:
        """Every skill, by name (all pages)."""
        return self._drive(_all_pages("/skills", Skill.from_json))

    def get_skill(self, name: str) -> Skill:
        """One skill with its counts and latest model version."""
        return self._call(_get_skill(name))

    def delete_skill(self, name: str) -> None:
        """Delete a skill with its demonstrations and models."""
        self._call(_delete(_skill_path(name)))

    # -- demonstrations --

    def add_demo(self, skill: str, positions: ArrayLike, timestamps: ArrayLike | None = None,
                 orientations: ArrayLike | None = None, label: str | None = None) -> DemoCreated:
        """Add one demonstration: positions (T, D), optional timestamps (T,) and unit
        quaternions (T, 4) as qx, qy, qz, qw. Numpy arrays or nested lists."""
        return self._call(_add_demo(skill, _demo_payload(positions, timestamps, orientations,
                                                         label)))

    def upload_demo_file(self, skill: str, path: str | os.PathLike[str], *,
                         format: str | None = None, topic: str | None = None,
                         label: str | None = None) -> DemoCreated:
        """Add one demonstration from a file: CSV, NPY or MCAP (``topic`` picks the pose
        topic) are uploaded as they are; a JSON file (``{"positions": ..., "timestamps"?, ...}``
        or a list of rows) is sent like :meth:`add_demo`. ``format`` overrides the suffix."""
        p = Path(path)
        guess_format(p, format)
        return self._call(_upload(skill, p, p.read_bytes(), format, topic, label))

    def list_demos(self, skill: str) -> list[DemoSummary]:
        """Summaries (no arrays) of every demonstration of a skill, oldest first."""
        return self._drive(_all_pages(_skill_path(skill, "demonstrations"),
                                      DemoSummary.from_json))

    def get_demo(self, skill: str, id: int) -> Demonstration:
        """One demonstration with its arrays as numpy."""
        return self._call(_get_demo(skill, id))

    def delete_demo(self, skill: str, id: int) -> None:
        """Delete one demonstration (model versions keep the ids they used)."""
        self._call(_delete(_skill_path(skill, "demonstrations", int(id))))

    # -- models --

    def fit(self, skill: str, *, cross_section: str | None = None, frames: str | None = None,
            alignment: str | None = None, directrix: str | None = None,
            n_samples: int | None = None, frame_smoothing: float | None = None,
            by_time: bool | None = None, demo_ids: Iterable[int] | None = None) -> ModelSummary:
        """Fit a new model version; options left ``None`` take the service's defaults."""
        return self._call(_fit(skill, dict(
            cross_section=cross_section, frames=frames, alignment=alignment,
            directrix=directrix, n_samples=n_samples, frame_smoothing=frame_smoothing,
            by_time=by_time, demo_ids=None if demo_ids is None else list(demo_ids))))

    def list_models(self, skill: str) -> list[ModelSummary]:
        """Every model version of a skill, newest first."""
        return self._drive(_all_pages(_skill_path(skill, "models"), ModelSummary.from_json))

    def get_model(self, skill: str, version: Version = "latest",
                  serialized: bool = False) -> Model:
        """A model version's geometry (with the canal_core dict when ``serialized``)."""
        return self._call(_get_model(skill, version, serialized))

    def get_canal(self, skill: str, version: Version = "latest") -> canal_core.Canal:
        """A model version as a local ``canal_core.Canal`` (reproduce, contains, tracker)."""
        return self._call(_get_canal(skill, version))

    def mesh(self, skill: str, version: Version = "latest", format: str = "ply",
             n_angles: int | None = None, caps: bool | None = None,
             envelope: bool | None = None) -> bytes:
        """The canal surface as ``ply``, ``obj``, ``glb`` or ``json`` bytes."""
        return self._call(_mesh(skill, version, format, n_angles, caps, envelope))

    # -- reproductions --

    def reproduce(self, skill: str, start: ArrayLike, *, model: Version = "latest",
                  outside: str = "project", goal: ArrayLike | None = None,
                  duration: float | None = None,
                  start_orientation: ArrayLike | None = None) -> Reproduction:
        """Reproduce from ``start`` (D,). A start outside the canal enters it over a short blend
        (``outside="project"``) or is refused with :class:`~canal_client.errors.OutsideCanalError`
        (``outside="raise"``). ``goal`` (D,) deforms the canal to end there; ``duration``
        (seconds) stretches the returned ``times``. ``start_orientation`` (4,) qx, qy, qz, qw:
        the start pose's orientation, carried along when the model has orientation
        (``result.orientations``); a model without it ignores it and says so in
        ``result.notes``."""
        return self._call(_reproduce(skill, start, model, outside, goal, duration, start_orientation))

    def reproduce_many(self, skill: str, starts: ArrayLike, *,
                       model: Version = "latest", outside: str = "project",
                       goal: ArrayLike | None = None, duration: float | None = None,
                       start_orientation: ArrayLike | None = None) -> list[Reproduction]:
        """Reproduce from each start (at most 1000) in one request, in order
        (``start_orientation`` is used for every start)."""
        return self._call(_reproduce_many(skill, starts, model, outside, goal, duration,
                                          start_orientation))

    # -- recordings --

    def download_recording(self, skill: str, kind: RecordingKind,
                           path: str | os.PathLike[str], *, profile: str | None = None) -> Path:
        """Stream the skill's ``.rrd`` or ``.mcap`` snapshot to ``path`` (written to a temporary
        file beside it, then renamed: ``path`` is either the whole file or untouched).
        ``profile="ros2"`` (mcap only): a rosbag2-compatible CDR file instead of Foxglove JSON."""
        target = Path(path)
        url = _recording_path(skill, kind)
        params = None if profile is None else {"profile": profile}
        with _atomic_file(target) as out:
            try:
                with self._http.stream("GET", url, params=params) as resp:
                    if not resp.is_success:
                        resp.read()
                        _check(resp)
                    for chunk in resp.iter_bytes(1 << 16):
                        out.write(chunk)
            except httpx.TransportError as exc:
                raise _transport_error(self.url, _timeout_of(self.timeout), exc) from exc
        return target

    def rebuild_recording(self, skill: str) -> dict[str, Any]:
        """Regenerate the skill's recordings from the service's database (demonstrations and
        model versions); answers what was written (``demos``, ``models``)."""
        return self._call(_rebuild_recording(skill))


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

    async def _call(self, req: _Request[T]) -> T:
        try:
            resp = await self._http.request(req.method, req.path, **req.kwargs())
        except httpx.TransportError as exc:
            raise _transport_error(self.url, _timeout_of(self.timeout), exc) from exc
        _check(resp)
        return req.parse(resp)

    async def _drive(self, steps: Generator[_Request[Any], Any, T]) -> T:
        try:
            req = next(steps)
            while True:
                req = steps.send(await self._call(req))
        except StopIteration as stop:
            return stop.value  # type: ignore[no-any-return]

    async def health(self) -> Health:
        """See :meth:`CanalClient.health`."""
        return await self._call(_health())

    async def create_skill(self, name: str, dim: int = 3, description: str = "") -> Skill:
        """See :meth:`CanalClient.create_skill`."""
        return await self._call(_create_skill(name, dim, description))

    async def list_skills(self) -> list[Skill]:
        """See :meth:`CanalClient.list_skills`."""
        return await self._drive(_all_pages("/skills", Skill.from_json))

    async def get_skill(self, name: str) -> Skill:
        """See :meth:`CanalClient.get_skill`."""
        return await self._call(_get_skill(name))

    async def delete_skill(self, name: str) -> None:
        """See :meth:`CanalClient.delete_skill`."""
        await self._call(_delete(_skill_path(name)))

    async def add_demo(self, skill: str, positions: ArrayLike,
                       timestamps: ArrayLike | None = None,
                       orientations: ArrayLike | None = None,
                       label: str | None = None) -> DemoCreated:
        """See :meth:`CanalClient.add_demo`."""
        return await self._call(_add_demo(skill, _demo_payload(positions, timestamps,
                                                               orientations, label)))

    async def upload_demo_file(self, skill: str, path: str | os.PathLike[str], *,
                               format: str | None = None, topic: str | None = None,
                               label: str | None = None) -> DemoCreated:
        """See :meth:`CanalClient.upload_demo_file` (the file is read in a worker thread)."""
        p = Path(path)
        guess_format(p, format)
        data = await asyncio.to_thread(p.read_bytes)
        return await self._call(_upload(skill, p, data, format, topic, label))

    async def list_demos(self, skill: str) -> list[DemoSummary]:
        """See :meth:`CanalClient.list_demos`."""
        return await self._drive(_all_pages(_skill_path(skill, "demonstrations"),
                                            DemoSummary.from_json))

    async def get_demo(self, skill: str, id: int) -> Demonstration:
        """See :meth:`CanalClient.get_demo`."""
        return await self._call(_get_demo(skill, id))

    async def delete_demo(self, skill: str, id: int) -> None:
        """See :meth:`CanalClient.delete_demo`."""
        await self._call(_delete(_skill_path(skill, "demonstrations", int(id))))

    async def fit(self, skill: str, *, cross_section: str | None = None,
                  frames: str | None = None, alignment: str | None = None,
                  directrix: str | None = None, n_samples: int | None = None,
                  frame_smoothing: float | None = None, by_time: bool | None = None,
                  demo_ids: Iterable[int] | None = None) -> ModelSummary:
        """See :meth:`CanalClient.fit`."""
        return await self._call(_fit(skill, dict(
            cross_section=cross_section, frames=frames, alignment=alignment,
            directrix=directrix, n_samples=n_samples, frame_smoothing=frame_smoothing,
            by_time=by_time, demo_ids=None if demo_ids is None else list(demo_ids))))

    async def list_models(self, skill: str) -> list[ModelSummary]:
        """See :meth:`CanalClient.list_models`."""
        return await self._drive(_all_pages(_skill_path(skill, "models"),
                                            ModelSummary.from_json))

    async def get_model(self, skill: str, version: Version = "latest",
                        serialized: bool = False) -> Model:
        """See :meth:`CanalClient.get_model`."""
        return await self._call(_get_model(skill, version, serialized))

    async def get_canal(self, skill: str, version: Version = "latest") -> canal_core.Canal:
        """See :meth:`CanalClient.get_canal`."""
        return await self._call(_get_canal(skill, version))

    async def mesh(self, skill: str, version: Version = "latest", format: str = "ply",
                   n_angles: int | None = None, caps: bool | None = None,
                   envelope: bool | None = None) -> bytes:
        """See :meth:`CanalClient.mesh`."""
        return await self._call(_mesh(skill, version, format, n_angles, caps, envelope))

    async def reproduce(self, skill: str, start: ArrayLike, *, model: Version = "latest",
                        outside: str = "project", goal: ArrayLike | None = None,
                        duration: float | None = None,
                        start_orientation: ArrayLike | None = None) -> Reproduction:
        """See :meth:`CanalClient.reproduce`."""
        return await self._call(_reproduce(skill, start, model, outside, goal, duration,
                                           start_orientation))

    async def reproduce_many(self, skill: str, starts: ArrayLike, *,
                             model: Version = "latest", outside: str = "project",
                             goal: ArrayLike | None = None, duration: float | None = None,
                             start_orientation: ArrayLike | None = None) -> list[Reproduction]:
        """See :meth:`CanalClient.reproduce_many`."""
        return await self._call(_reproduce_many(skill, starts, model, outside, goal, duration,
                                                start_orientation))

    async def download_recording(self, skill: str, kind: RecordingKind,
                                 path: str | os.PathLike[str], *,
                                 profile: str | None = None) -> Path:
        """See :meth:`CanalClient.download_recording`."""
        target = Path(path)
        url = _recording_path(skill, kind)
        params = None if profile is None else {"profile": profile}
        with _atomic_file(target) as out:
            try:
                async with self._http.stream("GET", url, params=params) as resp:
                    if not resp.is_success:
                        await resp.aread()
                        _check(resp)
                    async for chunk in resp.aiter_bytes(1 << 16):
                        out.write(chunk)
            except httpx.TransportError as exc:
                raise _transport_error(self.url, _timeout_of(self.timeout), exc) from exc
        return target

    async def rebuild_recording(self, skill: str) -> dict[str, Any]:
        """See :meth:`CanalClient.rebuild_recording`."""
        return await self._call(_rebuild_recording(skill))
