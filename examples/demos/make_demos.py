"""Write the four example demonstrations in this folder, one per accepted file format.

    python examples/demos/make_demos.py            # rewrites examples/demos/demo_*.*
    python examples/demos/make_demos.py --out DIR

The shape is the paper's Task I (Ahmadzadeh & Chernova, Sec. 5.1; ``canal_core.datasets.task_one``):
four 3-D demonstrations along x, 0.2 apart at the ends and 0.01 apart mid-way, sampled at
10 Hz over 4 s with a little noise. Each demonstration goes to one format:

=================  ==========================================================================
``demo_1.csv``     header ``t,x,y,z``
``demo_2.npy``     array (T, 4), time in column 0
``demo_3.json``    ``{"positions": [[x, y, z], ...], "timestamps": [...], "label": ...}``
``demo_4.mcap``    ROS 2 bag: ``geometry_msgs/msg/PoseStamped`` (CDR) on topic ``/ee_pose``
=================  ==========================================================================

``canal demo add SKILL examples/demos/`` uploads all four. Seeded: the same command writes
the same numbers.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from canal_service.recording.ros2_msgdefs import MSGDEFS

from canal_core import datasets

HERE = Path(__file__).resolve().parent
TOPIC = "/ee_pose"
RATE_HZ = 10.0

# geometry_msgs/msg/PoseStamped with its dependencies, as ROS 2 bags store it (ros2msg).
POSE_STAMPED_MSGDEF = MSGDEFS["geometry_msgs/msg/PoseStamped"]


def demonstrations(seed: int = 7) -> list[tuple[np.ndarray, np.ndarray]]:
    """Four (timestamps (T,), positions (T, 3)) pairs: Task I with 2 mm noise, 10 Hz."""
    demos = datasets.task_one(n_points=41, noise=0.002, seed=seed)
    return [(np.round(np.arange(len(d)) / RATE_HZ, 3), np.round(d, 5)) for d in demos]


def write_csv(path: Path, t: np.ndarray, x: np.ndarray) -> None:
    np.savetxt(path, np.column_stack([t, x]), delimiter=",", header="t,x,y,z", comments="",
               fmt="%.6g")


def write_npy(path: Path, t: np.ndarray, x: np.ndarray) -> None:
    np.save(path, np.column_stack([t, x]).astype(np.float64))


def write_json(path: Path, t: np.ndarray, x: np.ndarray) -> None:
    doc = {"positions": x.tolist(), "timestamps": t.tolist(), "label": "from-json"}
    path.write_text(json.dumps(doc) + "\n")


def write_ros2_mcap(path: Path, t: np.ndarray, x: np.ndarray) -> None:
    """A ROS 2 bag in MCAP form with one PoseStamped per sample (stamp = sample time)."""
    from mcap_ros2.writer import Writer as Ros2Writer

    t0 = 1_700_000_000_000_000_000  # ns; the service keeps times relative to the first sample
    with path.open("wb") as f:
        writer = Ros2Writer(f)
        schema = writer.register_msgdef("geometry_msgs/msg/PoseStamped", POSE_STAMPED_MSGDEF)
        for ti, p in zip(t, x, strict=True):
            stamp = t0 + round(float(ti) * 1e9)
            msg = {"header": {"stamp": {"sec": stamp // 10**9, "nanosec": stamp % 10**9},
                              "frame_id": "base_link"},
                   "pose": {"position": {"x": float(p[0]), "y": float(p[1]), "z": float(p[2])},
                            "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}}
            writer.write_message(TOPIC, schema, msg, log_time=stamp, publish_time=stamp)
        writer.finish()


WRITERS = (("demo_1.csv", write_csv), ("demo_2.npy", write_npy), ("demo_3.json", write_json),
           ("demo_4.mcap", write_ros2_mcap))


def write_all(out: Path, seed: int = 7) -> list[Path]:
    """Write the four files into ``out``; returns their paths."""
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for (name, writer), (t, x) in zip(WRITERS, demonstrations(seed), strict=True):
        writer(out / name, t, x)
        paths.append(out / name)
    return paths


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, default=HERE)
    p.add_argument("--seed", type=int, default=7)
    args = p.parse_args(argv)
    for path in write_all(args.out, args.seed):
        print(f"wrote {path} ({path.stat().st_size} bytes)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
