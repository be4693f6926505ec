"""What the service tells the recorder, as queued records, and their array views for the logs.

Caller side: each record method builds one small record (no numpy work beyond a defensive copy
of a demo) and queues it. Writer side: the views below turn records into the arrays both logs
(Rerun, MCAP) draw from.
"""

from __future__ import annotations

import threading
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Any, NamedTuple

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


@dataclass(slots=True)
class ModelFitted:
    t_ns: int
    skill: str
    version: int
    canal: Any  # canal_core.Canal: immutable, so holding a reference is safe


@dataclass(slots=True)
class ReproductionMade:
    t_ns: int
    skill: str
    version: int
    result: Any  # canal_core.Reproduction (immutable)


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


ControlEvent = (DemoAdded | DemoRef | ModelRef | DemoRemoved | ModelFitted | ReproductionMade
                | SkillDeleted | Rotate | Rebuild | Reconcile | Stop)

POSE, TARGET = 0, 1


class LiveSample(NamedTuple):
    """One live pose (robot -> Canal) or target (Canal -> robot), as plain Python values.

    ``kind`` is :data:`POSE` or :data:`TARGET`; ``position`` is the pose's position or the
    target's; the tracker fields are those of a target (zeros for a pose).
    """

    skill: str
    robot: str
    kind: int
    t_ns: int
    position: list[float]
    orientation: list[float] | None
    progress: float = 0.0
    eta: float = float("nan")
    section_index: int = -1
    inside: bool = False
    done: bool = False


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
    """The 3-D view of a ``canal_core.Reproduction`` (orientations and times when present)."""
    return ReproductionView(
        version=int(version), positions=points3d(result.positions), start=points3d(result.start),
        inside=bool(result.inside), eta=float(result.eta),
        section_index=int(result.section_index), projected=bool(result.projected),
        number=int(number), orientations=_optional(result, "orientations", 4),
        times=_optional(result, "times", None),
    )


@dataclass(frozen=True)
class LiveBatch:
    """Consecutive live samples of one robot on one skill, as columns."""

    robot: str
    kind: int  # POSE or TARGET
    t_ns: NDArray[np.int64]  # (M,)
    position: FloatArray  # (M, 3)
    orientation: FloatArray  # (M, 4) [qx, qy, qz, qw]; identity where the sample had none
    has_orientation: NDArray[np.bool_]  # (M,)
    progress: FloatArray  # (M,)
    eta: FloatArray  # (M,)
    section_index: NDArray[np.int64]  # (M,)
    inside: NDArray[np.bool_]  # (M,)
    done: NDArray[np.bool_]  # (M,)

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])


_IDENTITY = [0.0, 0.0, 0.0, 1.0]


def live_batches(samples: list[LiveSample]) -> dict[str, list[LiveBatch]]:
    """Samples grouped by skill, robot and kind, as column batches in arrival order."""
    groups: dict[tuple[str, str, int], list[LiveSample]] = defaultdict(list)
    for s in samples:
        groups[(s.skill, s.robot, s.kind)].append(s)
    out: dict[str, list[LiveBatch]] = defaultdict(list)
    for (skill, robot, kind), rows in groups.items():
        dim = max(len(r.position) for r in rows)
        pos = np.zeros((len(rows), dim))
        for i, r in enumerate(rows):  # positions of one stream share D; pad defensively
            pos[i, :len(r.position)] = r.position
        has_q = np.array([r.orientation is not None for r in rows], dtype=bool)
        quats = np.array([r.orientation if r.orientation is not None else _IDENTITY
                          for r in rows], dtype=np.float64)
        cols = list(zip(*rows, strict=True))
        out[skill].append(LiveBatch(
            robot=robot, kind=kind,
            t_ns=np.asarray(cols[3], dtype=np.int64),
            position=points3d(pos[:, :3]),
            orientation=quats, has_orientation=has_q,
            progress=np.asarray(cols[6], dtype=np.float64),
            eta=np.asarray(cols[7], dtype=np.float64),
            section_index=np.asarray(cols[8], dtype=np.int64),
            inside=np.asarray(cols[9], dtype=bool),
            done=np.asarray(cols[10], dtype=bool),
        ))
    return out

