"""Orientation quality, leave-one-out: the rotational ratio rule vs the phase-wise mean.

Run: ``.venv/bin/python bench/orientation.py`` (``--quick``: fewer synthetic instances).

Protocol: for every demo k of a set, fit the canal (default options, ``orientations=``) on the
other demos and reproduce from demo k's first pose (position and quaternion). Demo k's
orientation is resampled on its own phase (arc length of its cleaned positions, as the fit
aligns) at every cross-section; the angle between it and the reproduced orientation is taken
at every section the reproduction passes after the start (the start row is demo k's own
quaternion and would flatter every rule). Rows: median, 90th percentile and the angle at the
last section, over all held-out demos and sections, in degrees.

Methods:

* ``canal (learned carry)``: ``Canal.reproduce_detailed(start, start_orientation=q0)``: the
  start's offset from the section mean, scaled by how much the training demos' offsets
  persisted (canal_core.orientation).
* ``phase-wise mean`` (baseline): the training demos' mean orientation at each section (what
  the canal answers without a start orientation).
* ``constant offset`` (ablation): the start's offset from its section mean carried unchanged.
* ``spread-ratio rule`` (ablation): the position ratio rule transposed, the offset's angle kept
  at a constant fraction (<= 1) of the section's spread.
* ``offset -> 0 at end`` (ablation): the offset decayed linearly in arc length to the end.

Data: the five real UR5e demos (``../shared/data`` or ``tests/data``; their quaternions, q and
-q both occur), and synthetic pours (a carry then a tilt of up to ~100 deg about the tool's y
axis; per-demo grasp yaw offsets, tilt amplitudes, position offsets and 1 deg noise).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

import canal_core
from canal_core.alignment import spline_parameter
from canal_core.orientation import (
    aligned_orientations,
    angles_between,
    carried_orientations,
    start_offset,
)
from canal_core.preprocess import prepared_rows

if __package__:
    from bench.common import best_of, summary_row, write_summary
else:  # run as a file (python bench/x.py): bench/ is sys.path[0]
    from common import best_of, summary_row, write_summary

ROOT = Path(__file__).resolve().parent.parent
UR5E = [ROOT.parent / "shared" / "data" / "ur5e_lab_demos.npz", ROOT / "tests" / "data" / "ur5e_lab_demos.npz"]
N = 200
METHODS = ("canal (learned carry)", "phase-wise mean", "constant offset", "spread-ratio rule",
           "offset -> 0 at end")


def ur5e_demos() -> tuple[list[np.ndarray], list[np.ndarray]] | None:
    path = next((p for p in UR5E if p.exists()), None)
    if path is None:
        return None
    data = np.load(path)
    n = int(data["n_demos"])
    return [data[f"demo{i}_pos"] for i in range(n)], [data[f"demo{i}_quat"] for i in range(n)]


def pour_demos(seed: int, n: int = 6, t: int = 300) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Synthetic pours: carry over 60 % of the path, then tilt about the tool's y axis."""
    rng = np.random.default_rng(seed)
    demos, quats = [], []
    for _ in range(n):
        s = np.linspace(0.0, 1.0, t)
        offset = rng.normal(0.0, 0.02, 3)
        pos = np.column_stack([0.5 * s, 0.15 * np.sin(np.pi * s), 0.2 + 0.1 * np.sin(np.pi * s)])
        pos += offset * (1.0 - s)[:, None] + rng.normal(0.0, 5e-4, (t, 3))
        tilt_max = np.radians(rng.normal(100.0, 8.0))
        phase = np.clip((s - 0.6) / 0.4, 0.0, 1.0)
        tilt = tilt_max * phase * phase * (3.0 - 2.0 * phase)
        yaw = np.radians(rng.normal(0.0, 10.0))  # grasp heading: kept through the pour
        base = Rotation.from_euler("z", yaw) * Rotation.from_euler("x", 180.0, degrees=True)
        rot = base * Rotation.from_euler("y", tilt[:, None]) * Rotation.from_rotvec(rng.normal(0.0, np.radians(1.0), (t, 3)))
        q = rot.as_quat()
        q[rng.random(t) < 0.3] *= -1.0  # drivers flip signs freely
        demos.append(pos)
        quats.append(q)
    return demos, quats


def held_out_truth(demo: np.ndarray, quat: np.ndarray) -> np.ndarray:
    """Demo's orientation at N phases (arc length of its cleaned positions), shape (N, 4)."""
    rows = prepared_rows(demo, field="held-out demo")
    u = spline_parameter(demo[rows], None)
    return aligned_orientations([quat[rows]], [u], np.linspace(0.0, 1.0, N)[None, :])[0]


def leave_one_out(demos: list[np.ndarray], quats: list[np.ndarray]) -> dict[str, list[np.ndarray]]:
    """Angles (degrees) per method and held-out demo, each shape (sections passed,)."""
    out: dict[str, list[np.ndarray]] = {m: [] for m in METHODS}
    for k in range(len(demos)):
        train = [j for j in range(len(demos)) if j != k]
        canal = canal_core.fit([demos[j] for j in train], orientations=[quats[j] for j in train], n_samples=N)
        assert canal.orientation is not None
        rep = canal.reproduce_detailed(demos[k][0], start_orientation=quats[k][0])
        assert rep.orientations is not None
        first = N - (rep.positions.shape[0] - 1)
        truth = held_out_truth(demos[k], quats[k])[first:]
        model = canal.orientation
        i0 = rep.section_index
        offset = start_offset(model.means[i0], quats[k][0] / np.linalg.norm(quats[k][0]))
        angle = float(np.linalg.norm(offset))
        ratio = min(angle / max(float(model.spreads[i0]), 1e-12), 1.0)
        ratio_gain = ratio * model.spreads[first:] / max(angle, 1e-12)
        s = canal.arclength / canal.arclength[-1]
        fade = (1.0 - s[first:]) / max(1.0 - s[i0], 1e-12)
        means = model.means[first:]
        guesses = {
            "canal (learned carry)": rep.orientations[1:],
            "phase-wise mean": means,
            "constant offset": carried_orientations(means, np.ones(len(means)), offset),
            "spread-ratio rule": carried_orientations(means, ratio_gain, offset),
            "offset -> 0 at end": carried_orientations(means, fade, offset),
        }
        for m, q in guesses.items():
            out[m].append(np.degrees(angles_between(q, truth)))
    return out


def table(name: str, results: dict[str, list[np.ndarray]]) -> list[str]:
    lines = []
    for m in METHODS:
        flat = np.concatenate(results[m])
        end = np.array([a[-1] for a in results[m]])
        lines.append(f"| {name} | {m} | {np.median(flat):.2f} | {np.percentile(flat, 90):.2f} | "
                     f"{np.median(end):.2f} |")
    return lines


def cost_table(data: tuple[list[np.ndarray], list[np.ndarray]]) -> list[str]:
    """Fit and reproduce with orientation against the same calls without (best of 5, ms)."""
    demos, quats = data
    rows = ["| call (N = 200) | positions only ms | with orientation ms | ratio |", "|---|---|---|---|"]
    plain_fit = best_of(lambda: canal_core.fit(demos, n_samples=N), 5)
    pose_fit = best_of(lambda: canal_core.fit(demos, orientations=quats, n_samples=N), 5)
    plain = canal_core.fit(demos, n_samples=N)
    pose = canal_core.fit(demos, orientations=quats, n_samples=N)
    plain_rep = best_of(lambda: plain.reproduce_detailed(demos[0][0]), 20)
    pose_rep = best_of(lambda: pose.reproduce_detailed(demos[0][0], start_orientation=quats[0][0]), 20)
    for name, a, b in (("fit", plain_fit, pose_fit), ("reproduce_detailed", plain_rep, pose_rep)):
        rows.append(f"| {name} | {1e3 * a:.2f} | {1e3 * b:.2f} | {b / a:.2f} |")
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="2 synthetic instances instead of 5")
    args = parser.parse_args(argv)
    lines = ["| data | method | median deg | p90 deg | median at end deg |", "|---|---|---|---|---|"]
    summary = []
    real = ur5e_demos()
    if real is None:
        print("UR5e demos not found (../shared/data or tests/data): skipped")
    else:
        res = leave_one_out(*real)
        lines += table("UR5e (5 real demos)", res)
        summary.append(summary_row(
            "orientation LOO median angle, UR5e", float(np.median(np.concatenate(res[METHODS[0]]))), "deg",
            peer_name="phase-wise mean", peer_value=float(np.median(np.concatenate(res[METHODS[1]]))),
            better="lower"))
    merged: dict[str, list[np.ndarray]] = {m: [] for m in METHODS}
    instances = 2 if args.quick else 5
    for seed in range(instances):
        for m, v in leave_one_out(*pour_demos(seed)).items():
            merged[m] += v
    lines += table(f"synthetic pour ({instances} x 6 demos)", merged)
    summary.append(summary_row(
        "orientation LOO median angle, synthetic pour", float(np.median(np.concatenate(merged[METHODS[0]]))),
        "deg", peer_name="phase-wise mean", peer_value=float(np.median(np.concatenate(merged[METHODS[1]]))),
        better="lower"))
    print("\n".join(lines))
    print("\n" + "\n".join(cost_table(real if real is not None else pour_demos(0))))
    write_summary("orientation", summary)
    return 0


if __name__ == "__main__":
    sys.exit(main())
