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
class Stop:
    """Drain, close every segment and end the writer thread."""


ControlEvent = DemoAdded | DemoRemoved | ModelFitted | ReproductionMade | SkillDeleted | Rotate | Stop


class LiveSample(NamedTuple):
    """One live tracker step (plain Python values: cheap to build, safe to keep)."""

    skill: str
    robot: str
    t_ns: int
    position: list[float]
    target: list[float]
    progress: float
    eta: float
    section_index: int
    inside: bool
    done: bool


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


def reproduction_view(version: int, result: Any) -> ReproductionView:
    """The 3-D view of a ``canal_core.Reproduction``."""
    return ReproductionView(
        version=int(version), positions=points3d(result.positions), start=points3d(result.start),
        inside=bool(result.inside), eta=float(result.eta),
        section_index=int(result.section_index), projected=bool(result.projected),
    )


@dataclass(frozen=True)
class LiveBatch:
    """Consecutive live samples of one robot on one skill, as columns."""

    robot: str
    t_ns: NDArray[np.int64]  # (M,)
    position: FloatArray  # (M, 3)
    target: FloatArray  # (M, 3)
    progress: FloatArray  # (M,)
    eta: FloatArray  # (M,)
    section_index: NDArray[np.int64]  # (M,)
    inside: NDArray[np.bool_]  # (M,)
    done: NDArray[np.bool_]  # (M,)

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])


def live_batches(samples: list[LiveSample]) -> dict[str, list[LiveBatch]]:
    """Samples grouped by skill then robot, as column batches in arrival order."""
    groups: dict[tuple[str, str], list[LiveSample]] = defaultdict(list)
    for s in samples:
        groups[(s.skill, s.robot)].append(s)
    out: dict[str, list[LiveBatch]] = defaultdict(list)
    for (skill, robot), rows in groups.items():
        cols = list(zip(*rows, strict=True))
        out[skill].append(LiveBatch(
            robot=robot,
            t_ns=np.asarray(cols[2], dtype=np.int64),
            position=points3d(np.asarray(cols[3], dtype=np.float64)),
            target=points3d(np.asarray(cols[4], dtype=np.float64)),
            progress=np.asarray(cols[5], dtype=np.float64),
            eta=np.asarray(cols[6], dtype=np.float64),
            section_index=np.asarray(cols[7], dtype=np.int64),
            inside=np.asarray(cols[8], dtype=bool),
            done=np.asarray(cols[9], dtype=bool),
        ))
    return out

