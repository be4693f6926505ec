"""What the service tells the recorder, as queued records, and their array views for the logs.

Caller side: each record method builds one small record (no numpy work beyond a defensive copy
of a demo) and queues it. Writer side: the views below turn records into the arrays both logs
(Rerun, MCAP) draw from.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .geometry import FloatArray, points3d


@dataclass(slots=True)
class DemoAdded:
    t_ns: int
    skill: str
    demo_id: int
    positions: FloatArray  # (T, D), a copy: the caller may reuse its buffer
    timestamps: FloatArray | None  # (T,)
    label: str | None
    orientations: FloatArray | None = None  # (T, 4) [qx, qy, qz, qw]


@dataclass(slots=True)
class DemoRef:
    """A stored demonstration, by id: the writer reads its arrays from the database."""

    t_ns: int
    skill: str
    demo_id: int


@dataclass(slots=True)
class ModelRef:
    """A stored model version, by number: the writer reads the canal from the database."""

    t_ns: int
    skill: str
    version: int


@dataclass(slots=True)
class DemoRemoved:
    t_ns: int
    skill: str
    demo_id: int
    instance: str | None = None  # the skill instance it was removed from, when known


@dataclass(slots=True)
class ModelFitted:
    t_ns: int
    skill: str
    version: int
    #: canal_core.Canal, or canal_core.Routes for a model of several routes: immutable, so
    #: holding a reference is safe
    canal: Any
    instance: str | None = None  # the skill instance it was fitted for, when known


@dataclass(slots=True)
class ReproductionMade:
    t_ns: int
    skill: str
    version: int
    result: Any  # canal_core.Reproduction (immutable)
    number: int | None = None  # the database's number when it was kept, else the recorder's
    instance: str | None = None  # the skill instance it was computed for, when known


@dataclass(slots=True)
class SceneChanged:
    t_ns: int
    skill: str
    version: int
    obstacles: list[dict[str, Any]]  # canal_core's JSON form, as stored
    dim: int
    instance: str | None = None  # the skill instance whose scene it is, when known


@dataclass(slots=True)
class SkillDeleted:
    t_ns: int
    skill: str


@dataclass(slots=True)
class Rotate:
    """Close the skill's open segment so an export sees everything queued before it."""

    skill: str
    done: threading.Event = field(default_factory=threading.Event)
    error: str | None = None


@dataclass(slots=True)
class Rebuild:
    """Regenerate the skill's recording from the database (``result``: what was logged)."""

    skill: str
    done: threading.Event = field(default_factory=threading.Event)
    result: dict[str, Any] = field(default_factory=dict)


@dataclass(slots=True)
class Reconcile:
    """Log what the database holds and the recording misses (all skills when None)."""

    skill: str | None = None
    done: threading.Event = field(default_factory=threading.Event)
    result: dict[str, Any] = field(default_factory=dict)


@dataclass(slots=True)
class Stop:
    """Drain, close every segment and end the writer thread."""


ControlEvent = (DemoAdded | DemoRef | ModelRef | DemoRemoved | ModelFitted | ReproductionMade | SceneChanged
                | SkillDeleted | Rotate | Rebuild | Reconcile | Stop)

@dataclass(frozen=True)
class ReproductionView:
    """A reproduction in 3-D for the logs."""

    version: int
    positions: FloatArray  # (M, 3)
    start: FloatArray  # (3,)
    inside: bool
    eta: float
    section_index: int
    projected: bool
    number: int = 0  # the skill's n-th reproduction: its own entity in both logs
    orientations: FloatArray | None = None  # (M, 4) unit [qx, qy, qz, qw], when the model has them
    times: FloatArray | None = None  # (M,) seconds from the start, when the model has them
    ratios: FloatArray | None = None  # (M,) each position's ratio (the start's first)
    #: What the reproduction had that the logs cannot hold in full (left out, and counted)
    incomplete: tuple[str, ...] = ()


#: Longest time span a log can hold: both logs keep times as int64 nanoseconds.
MAX_RECORDABLE_SECONDS = (2**63 - 1) / 1e9 / 2


def _optional(result: Any, name: str, cols: int | None) -> FloatArray | None:
    value = getattr(result, name, None)
    if value is None:
        return None
    arr = np.asarray(value, dtype=np.float64)
    n = len(result.positions)
    if arr.shape[0] != n or (cols is not None and (arr.ndim != 2 or arr.shape[1] != cols)):
        return None  # not what the contract says: draw without it rather than fail
    return arr


def reproduction_view(version: int, result: Any, number: int = 0) -> ReproductionView:
    """The 3-D view of a ``canal_core.Reproduction`` (orientations and times when present).

    Orientations or times the logs cannot hold (not finite, not one per position, times
    beyond :data:`MAX_RECORDABLE_SECONDS` of int64 nanoseconds) are left out whole, never
    half-written, and named in ``incomplete`` for the recorder to count.
    """
    orientations = _optional(result, "orientations", 4)
    times = _optional(result, "times", None)
    incomplete = []
    if orientations is not None and not np.isfinite(orientations).all():
        orientations = None
    if orientations is None and getattr(result, "orientations", None) is not None:
        incomplete.append("orientations")
    if times is not None and not (np.isfinite(times).all() and float(np.abs(
            times - times[0]).max(initial=0.0)) <= MAX_RECORDABLE_SECONDS):
        times = None
    if times is None and getattr(result, "times", None) is not None:
        incomplete.append("times")
    ratios = _optional(result, "ratios", None)
    if ratios is not None and not np.isfinite(ratios).all():
        ratios = None
    if ratios is None and getattr(result, "ratios", None) is not None:
        incomplete.append("ratios")
    return ReproductionView(
        version=int(version), positions=points3d(result.positions), start=points3d(result.start),
        inside=bool(result.inside), eta=float(result.eta),
        section_index=int(result.section_index), projected=bool(result.projected),
        number=int(number), orientations=orientations, times=times, ratios=ratios,
        incomplete=tuple(incomplete),
    )


@dataclass(frozen=True, slots=True)
class LiveRows:
    """Consecutive live rows of one robot on one skill, as columns: each row is a pose
    (robot -> Canal) and the target Canal answered to it."""

    skill: str
    robot: str
    t_ns: NDArray[np.int64]  # (M,)
    position: FloatArray  # (M, 3), 2-D poses in the z=0 plane
    orientation: FloatArray  # (M, 4) [qx, qy, qz, qw]; identity where the pose had none
    target: FloatArray  # (M, 3)
    target_orientation: FloatArray  # (M, 4); identity where the target had none
    progress: FloatArray  # (M,)
    eta: FloatArray  # (M,)
    section_index: NDArray[np.int64]  # (M,)
    inside: NDArray[np.bool_]  # (M,)
    done: NDArray[np.bool_]  # (M,)
    route: NDArray[np.int64]  # (M,) the route of a model of several routes; -1: one route

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])

    def tail(self, k: int) -> LiveRows:
        """The last ``k`` rows."""
        start = len(self) - k
        return LiveRows(self.skill, self.robot, *(getattr(self, f)[start:] for f in _COLUMNS))

    def after(self, t_ns: int) -> LiveRows:
        """The rows later than ``t_ns``."""
        keep = self.t_ns > t_ns
        return LiveRows(self.skill, self.robot, *(getattr(self, f)[keep] for f in _COLUMNS))


_COLUMNS = ("t_ns", "position", "orientation", "target", "target_orientation", "progress",
            "eta", "section_index", "inside", "done", "route")


def live_rows(skill: str, robot: str, t_ns: Any, position: Any, orientation: Any,
              target: Any, target_orientation: Any, progress: Any, eta: Any,
              section_index: Any, inside: Any, done: Any, route: Any = None) -> LiveRows:
    """Columns as :class:`LiveRows`: positions and targets (M, D) drawn in 3-D, missing
    orientations (None) as the identity, a missing route (None) as -1 (one route)."""
    t = np.asarray(t_ns, dtype=np.int64).reshape(-1)
    m = t.shape[0]

    def quats(q: Any) -> FloatArray:
        if q is None:
            return np.tile(_IDENTITY, (m, 1))
        return np.asarray(q, dtype=np.float64).reshape(m, 4)

    def points(p: Any) -> FloatArray:
        arr = np.asarray(p, dtype=np.float64).reshape(m, -1)
        return points3d(arr[:, :3])

    return LiveRows(skill, robot, t, points(position), quats(orientation), points(target),
                    quats(target_orientation),
                    np.asarray(progress, dtype=np.float64).reshape(m),
                    np.asarray(eta, dtype=np.float64).reshape(m),
                    np.asarray(section_index, dtype=np.int64).reshape(m),
                    np.asarray(inside, dtype=bool).reshape(m),
                    np.asarray(done, dtype=bool).reshape(m),
                    np.full(m, -1, dtype=np.int64) if route is None
                    else np.asarray(route, dtype=np.int64).reshape(m))


_IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


def concat_rows(chunks: list[LiveRows]) -> LiveRows:
    """Chunks of one stream (same skill and robot) as one, in order."""
    if len(chunks) == 1:
        return chunks[0]
    first = chunks[0]
    return LiveRows(first.skill, first.robot,
                    *(np.concatenate([getattr(c, f) for c in chunks]) for f in _COLUMNS))
