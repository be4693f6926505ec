"""Obstacles: canal reproductions around spheres against DMP's obstacle coupling term, leave-one-out.

DMP is movement_primitives' with its ``CouplingTermObstacleAvoidance3D``.

Run: ``.venv/bin/python bench/obstacles.py`` (full) or ``--quick`` (RAIL user 4 only, one
generated set per shape); ``python -m bench --only obstacles --write`` writes its section of
BENCHMARKS.md.

Sets: the real UR5e reaches (tests/data/ur5e_lab_demos.npz), the generated raw 3-D logs of
tests/raw_logs.py (task1, task2, helix; 6 demos each), and the RAIL kinesthetic demos of users
4-10 (../shared/data/rail/, read by path, evaluation only; its README's protocol: still ends
trimmed, 200 points evenly in each demo's own time, no time stamps). Every demo is cleaned once
and both methods get the same arrays.

Per fold (each demo held out once): the canal is fitted on the others; one to three spheres are
placed at 25, 50 and 75 % of its directrix's length (which ones, at random), each of radius
0.3-0.6 of the local section radius, centred 0.3-0.5 of it off the directrix toward a random
side, so the canal always leaves room. Both methods reproduce from the held-out demo's first
point, scored against the spheres' own radii (no clearance):

* ``collision-free``: share of reproductions none of whose segments enters a sphere (the exact
  segment-to-sphere distance, not only the samples); a blocked canal reproduction counts (it
  stops short, outside every sphere) and is counted in ``blocked`` too;
* ``inside``: share of reproductions whose points after the first 10 % (the entry of a start
  outside the canal) all lie inside the canal;
* ``dtw``: DTW to the held-out demo, both resampled to 200 points by arc length, / 200;
* ``step``: the largest step after the first 10 %, over the demonstrations' largest step
  between sections (``Canal.largest_step``).

``canal, live`` is a first-order robot following the live tracker's answers around the same
spheres from the same start (the bridge's tracker bank and obstacle pass, lookahead 2, each
pose 30 % of the way to its target, at most 4,000 poses); its ``blocked`` is the share that
did not reach the end, and the headline compares how often it ends as the reproduction does
(both reach the end, or both are blocked).

DMP: movement_primitives' DMP (30 weights per dimension) fitted on the mean demo (200 points
in normalised time), goal the mean goal, started at the held-out start, with one
``CouplingTermObstacleAvoidance3D`` per sphere (the term sees the sphere's centre as a point)
summed; its gain gamma is swept and DMP's best gain per set is reported (most collision-free,
then lowest DTW), beside DMP without the term.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
from movement_primitives.dmp import DMP, CouplingTermObstacleAvoidance3D

import canal_core
from canal_core import metrics
from canal_core.obstacles import Scene, scene_from_list, segment_free_distances
from canal_core.preprocess import cleaned_demonstration

if __package__:
    from bench.common import summary_row, write_section, write_summary  # python -m bench.obstacles
else:
    from common import summary_row, write_section, write_summary  # python bench/obstacles.py

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))
from raw_logs import raw_demo_set, ur5e_demos  # noqa: E402

N = 200
DMP_WEIGHTS = 30
GAINS = (0.0, 30.0, 100.0, 300.0, 1000.0, 3000.0, 10000.0)
#: ../shared/data/rail/ from the repository (a git worktree sits one folder deeper).
RAIL = next((p for p in (ROOT.parent / "shared" / "data" / "rail",
                         ROOT.parent.parent / "shared" / "data" / "rail") if p.exists()),
            ROOT.parent / "shared" / "data" / "rail")
SKIP = 0.1  # the first 10 % of a reproduction is its entry

Demo = tuple[np.ndarray, np.ndarray]  # (timestamps (T,), positions (T, 3))


# -- data -------------------------------------------------------------------------------------


def cleaned(t: np.ndarray, pos: np.ndarray) -> Demo:
    p, s = cleaned_demonstration(np.asarray(pos, float), np.asarray(t, float))
    assert s is not None
    return s - s[0], p


def ur5e_sets() -> dict[str, list[Demo]]:
    pos, ts, _ = ur5e_demos()
    return {"UR5e reach": [cleaned(t, p) for t, p in zip(ts, pos, strict=True)]}


def raw3d_sets(seeds: int) -> dict[str, list[Demo]]:
    out = {}
    for shape in ("task1", "task2", "helix"):
        for seed in range(seeds):
            logs = raw_demo_set(shape, seed)
            out[f"raw {shape} #{seed}"] = [
                cleaned(g.timestamps[g.genuine], g.positions[g.genuine]) for g in logs]
    return out


def rail_sets(quick: bool) -> dict[str, list[Demo]]:
    """RAIL per its README: still ends (1 mm) trimmed, 200 points evenly in each demo's own time."""
    if not RAIL.exists():
        return {}
    files = sorted(RAIL.glob("*_raw.npz"))
    if quick:
        files = [f for f in files if "user4" in f.name]
    out = {}
    for f in files:
        data = np.load(f)
        demos = []
        for i in range(int(data["n_demos"])):
            key = f"demo{i}_pos" if f"demo{i}_pos" in data else f"demo{i + 1}_pos"
            if key not in data:
                continue
            t, p = cleaned(data[key.replace("_pos", "_t")], data[key])
            grid = np.linspace(t[0], t[-1], N)
            demos.append((np.linspace(0.0, 1.0, N), np.column_stack([np.interp(grid, t, p[:, d]) for d in range(3)])))
        if len(demos) >= 3:
            out[f.stem.removesuffix("_raw")] = demos
    return out


# -- the obstacles of one fold ----------------------------------------------------------------


def fold_spheres(canal: canal_core.Canal, rng: np.random.Generator) -> list[dict[str, Any]]:
    """1-3 spheres at 25/50/75 % of the directrix, radius 0.3-0.6 and offset 0.3-0.5 of the
    local section radius toward a random side."""
    count = int(rng.integers(1, 4))
    out = []
    for fraction in sorted(rng.choice([0.25, 0.5, 0.75], size=count, replace=False)):
        k = int(np.searchsorted(canal.arclength, fraction * canal.arclength[-1]))
        k = min(max(k, 0), canal.n_sections - 1)
        r = float(canal.radii[k])
        angle = rng.uniform(0.0, 2.0 * math.pi)
        assert canal.binormals is not None
        side = math.cos(angle) * canal.normals[k] + math.sin(angle) * canal.binormals[k]
        centre = canal.directrix[k] + rng.uniform(0.3, 0.5) * r * side
        out.append({"kind": "sphere", "center": centre.tolist(), "radius": float(rng.uniform(0.3, 0.6) * r)})
    return out


# -- methods ------------------------------------------------------------------------------------


class SummedCoupling:
    """Several coupling terms acting at once (one per obstacle): their accelerations add."""

    def __init__(self, terms: list[Any]) -> None:
        self.terms = terms

    def coupling(self, y: np.ndarray, yd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cd = np.zeros_like(y)
        cdd = np.zeros_like(y)
        for term in self.terms:
            a, b = term.coupling(y, yd)
            cd += a
            cdd += b
        return cd, cdd


def on_time_grid(t: np.ndarray, pos: np.ndarray) -> np.ndarray:
    u = (t - t[0]) / (t[-1] - t[0])
    grid = np.linspace(0.0, 1.0, N)
    return np.column_stack([np.interp(grid, u, pos[:, i]) for i in range(pos.shape[1])])


def dmp_fit(train: list[Demo]) -> tuple[DMP, np.ndarray]:
    mean = np.mean([on_time_grid(t, p) for t, p in train], axis=0)
    dmp = DMP(n_dims=3, execution_time=1.0, dt=1.0 / (N - 1), n_weights_per_dim=DMP_WEIGHTS)
    dmp.imitate(np.linspace(0.0, 1.0, N), mean)
    return dmp, mean[-1]


def dmp_reproduce(model: tuple[DMP, np.ndarray], start: np.ndarray, spheres: list[dict[str, Any]],
                  gain: float) -> np.ndarray:
    dmp, goal = model
    dmp.configure(start_y=start, goal_y=goal)
    coupling = None
    if gain > 0.0:
        coupling = SummedCoupling([CouplingTermObstacleAvoidance3D(np.asarray(s["center"]), gamma=gain)
                                   for s in spheres])
    _, y = dmp.open_loop(coupling_term=coupling, step_function="euler")
    return np.asarray(y, float)


def live_followed(canal: canal_core.Canal, start: np.ndarray, scene: Scene) -> tuple[np.ndarray, bool]:
    """The path of a first-order robot following the live tracker's answers around ``scene``
    from ``start`` (the bridge's tracker bank and obstacle pass, lookahead 2; each pose moves
    30 % of the way to its target, at most 4,000 poses), and whether it reached the end."""
    from canal_core.tracker_bank import TrackerBank
    from canal_core.tracker_obstacles import scene_tables

    bank = TrackerBank(canal.tracker_geometry(), 2)
    bank.scene = scene_tables(bank.geometry, scene, canal.section_steps)
    slot = bank.add(int(canal.reproduce_detailed(start).section_index))
    x = start[None, :].copy()
    path = [x[0].copy()]
    for _ in range(4000):
        rows = bank.step_packed([slot], x)
        bank.avoid_packed(rows, x)
        if rows[0, 7] != 0.0:
            return np.array(path), True
        x = x + 0.3 * (rows[:, :3] - x)
        path.append(x[0].copy())
    return np.array(path), False


# -- scoring ------------------------------------------------------------------------------------


def scored(canal: canal_core.Canal, y: np.ndarray, held: np.ndarray, scene: Scene) -> dict[str, float]:
    free = segment_free_distances(y[:-1], y[1:], scene)
    skip = math.ceil(SKIP * y.shape[0])
    tail = y[skip:]
    steps = np.linalg.norm(np.diff(tail, axis=0), axis=1)
    return {
        "free": float(free.min(initial=np.inf) >= -1e-9),
        "inside": float(bool(canal.contains(tail).all())) if tail.size else 1.0,
        "dtw": metrics.dtw_distance(metrics.resampled_by_arc_length(y, N),
                                    metrics.resampled_by_arc_length(held, N)) / N,
        "step": float(steps.max(initial=0.0)) / canal.largest_step,
    }


def evaluate(sets: dict[str, list[Demo]], seed: int) -> dict[str, dict[str, dict[str, list[float]]]]:
    """out[set][method][metric] -> per-fold values (methods: canal, DMP gamma=g for each gain)."""
    out: dict[str, dict[str, dict[str, list[float]]]] = {}
    for set_name, demos in sets.items():
        rows: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
        for k in range(len(demos)):
            train = demos[:k] + demos[k + 1:]
            _, held = demos[k]
            rng = np.random.default_rng([seed, k, sum(map(ord, set_name))])
            canal = canal_core.fit([p for _, p in train], [t for t, _ in train], n_samples=N)
            spheres = fold_spheres(canal, rng)
            scene = scene_from_list(spheres, 3)
            start = held[0]
            t0 = time.perf_counter()
            rep = canal.reproduce_detailed(start, obstacles=spheres)
            ms = 1e3 * (time.perf_counter() - t0)
            r = rows["canal"]
            for key, value in scored(canal, rep.positions, held, scene).items():
                r[key].append(value)
            r["blocked"].append(float(rep.blocked is not None))
            r["ms"].append(ms)
            if rep.blocked is not None:
                print(f"  {set_name}[{k}]: blocked at section {rep.blocked.section} "
                      f"({rep.blocked.reason})", flush=True)
            path, reached = live_followed(canal, start, scene)
            r = rows["canal, live"]
            for key, value in scored(canal, path, held, scene).items():
                r[key].append(value)
            r["blocked"].append(float(not reached))
            r["agrees"].append(float(reached == (rep.blocked is None)))
            plain = canal.reproduce_detailed(start).positions
            r = rows["canal without obstacles"]
            for key, value in scored(canal, plain, held, scene).items():
                r[key].append(value)
            r["blocked"].append(0.0)
            model = dmp_fit(train)
            for gain in GAINS:
                y = dmp_reproduce(model, start, spheres, gain)
                r = rows[f"DMP gamma={gain:g}"]
                if not np.all(np.isfinite(y)):
                    r["failed"].append(1.0)
                    continue
                for key, value in scored(canal, y, held, scene).items():
                    r[key].append(value)
                r["blocked"].append(0.0)
        out[set_name] = rows
    return out


def pooled(results: dict[str, dict[str, dict[str, list[float]]]], names: list[str]) -> dict[str, dict[str, list[float]]]:
    rows: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    for name in names:
        for method, metrics_ in results[name].items():
            for key, values in metrics_.items():
                rows[method][key].extend(values)
    return rows


def best_dmp(rows: dict[str, dict[str, list[float]]]) -> str:
    dmps = [m for m in rows if m.startswith("DMP gamma=") and m != "DMP gamma=0" and rows[m]["free"]]
    return max(dmps, key=lambda m: (np.mean(rows[m]["free"]), -np.median(rows[m]["dtw"])))


def table(groups: dict[str, dict[str, dict[str, list[float]]]]) -> str:
    lines = ["| set | folds | method | collision-free | blocked | inside | median dtw | largest step / demos' |",
             "|---|---|---|---|---|---|---|---|"]
    for group, rows in groups.items():
        best = best_dmp(rows)
        for method in ("canal", "canal, live", "canal without obstacles", best, "DMP gamma=0"):
            r = rows[method]
            n = len(r["free"])
            label = method if method != "DMP gamma=0" else "DMP without the term"
            if method == best:
                label = f"DMP + coupling term, best gain ({method.split('=')[1]})"
            if method == "canal, live":
                label = "canal, a live robot following it (blocked: did not reach the end)"
            lines.append(
                f"| {group} | {n} | {label} | {100 * np.mean(r['free']):.0f} % | "
                f"{100 * np.mean(r['blocked']):.0f} % | {100 * np.mean(r['inside']):.0f} % | "
                f"{np.median(r['dtw']):.4f} | {np.max(r['step']):.2f} |")
    return "\n".join(lines)


def live_cost(repeats: int = 300, robots: int = 16, obstacles: int = 10) -> tuple[float, float, float]:
    """Per-pose cost of the tracker bank's step for ``robots`` moving streams of the UR5e canal,
    alone and followed by the obstacle pass with a scene of ``obstacles`` spheres along the
    canal (both timed in this run, best of 3): (us without, us with, share of answers
    corrected)."""
    from canal_core.tracker_bank import TrackerBank
    from canal_core.tracker_obstacles import scene_tables

    demos = ur5e_sets()["UR5e reach"]
    canal = canal_core.fit([p for _, p in demos], [t for t, _ in demos], n_samples=N)
    rng = np.random.default_rng(7)
    spheres = []
    for k in np.linspace(0.1, 0.9, obstacles):
        i = int(k * (canal.n_sections - 1))
        r = float(canal.radii[i])
        assert canal.binormals is not None
        angle = rng.uniform(0.0, 2.0 * math.pi)
        side = math.cos(angle) * canal.normals[i] + math.sin(angle) * canal.binormals[i]
        spheres.append({"kind": "sphere", "center": (canal.directrix[i] + 0.4 * r * side).tolist(),
                        "radius": 0.4 * r})
    tables = scene_tables(canal.tracker_geometry(), scene_from_list(spheres, 3), canal.section_steps)
    # Robots at their own places along the canal, each moving 60 % of the way to its answer
    # per step (a lagging arm), started over at the beginning when done: one drain of 16 poses
    # per step, as the bridge steps them.
    idx = np.linspace(0, canal.n_sections // 2, robots).astype(int)
    starts = canal.directrix[idx] + 0.3 * canal.radii[idx, None] * canal.normals[idx]

    def run(with_scene: bool) -> tuple[float, float]:
        bank = TrackerBank(canal.tracker_geometry(), 2)
        bank.scene = tables if with_scene else None
        slots = [bank.add(int(i)) for i in idx]
        poses = starts.copy()
        spent, moved = 0.0, 0
        for _ in range(repeats):
            t0 = time.perf_counter()
            rows = bank.step_packed(slots, poses)
            status = bank.avoid_packed(rows, poses) if with_scene else None
            spent += time.perf_counter() - t0
            if status is not None:
                moved += int(np.count_nonzero(status))
            done = rows[:, 7] != 0.0
            poses = poses + 0.6 * (rows[:, :3] - poses)
            for r in np.flatnonzero(done):
                bank.reset(slots[r], int(idx[0]))
                poses[r] = starts[0]
        return spent / (repeats * robots) * 1e6, moved / (repeats * robots)

    plain = min(run(False)[0] for _ in range(3))
    scened, detoured = min(run(True) for _ in range(3))
    return plain, scened, detoured


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true", help="RAIL user 4 only, one generated set per shape")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    t_all = time.perf_counter()
    plan = {"UR5e": ur5e_sets(), "raw 3-D": raw3d_sets(1 if args.quick else 2), "RAIL": rail_sets(args.quick)}
    groups = {}
    for group, sets in plan.items():
        if not sets:
            print(f"{group}: no data, skipped")
            continue
        t0 = time.perf_counter()
        results = evaluate(sets, args.seed)
        groups[group] = pooled(results, list(sets))
        print(f"{group}: {len(sets)} set(s), {sum(len(d) for d in sets.values())} folds, "
              f"{time.perf_counter() - t0:.0f} s", flush=True)
    text = table(groups)
    print("\n" + text)
    canal_ms = [v for rows in groups.values() for v in rows["canal"]["ms"]]
    plain_us, scene_us, detoured = live_cost()
    live = (f"Live, the tracker bank's step for 16 streams of the UR5e canal (one drain, numpy or "
            f"compiled kernel as the bridge runs it): {plain_us:.1f} us a pose without a scene, "
            f"{scene_us:.1f} us with a 10-sphere scene ({scene_us / plain_us:.1f}x; "
            f"{100 * detoured:.0f} % of the answers corrected), same run. Not measured here: the "
            f"full 16 robots x 1 kHz Zenoh run with a scene (bench/live.py runs it without).")
    agree = "; ".join(f"{group} {int(np.sum(rows['canal, live']['agrees']))} of {len(rows['canal, live']['agrees'])}"
                      for group, rows in groups.items())
    live += (f" A live robot around the spheres ends as the reproduction does (both reach the end, "
             f"or both are blocked) in: {agree} folds.")
    print("\n" + live)
    total = time.perf_counter() - t_all
    print(f"\ncanal reproduction with obstacles: median {np.median(canal_ms):.0f} ms, "
          f"max {np.max(canal_ms):.0f} ms; total wall time {total:.0f} s")
    summary = []
    for group, rows in groups.items():
        best = best_dmp(rows)
        summary.append(summary_row(f"collision-free reproductions around spheres, {group}",
                                   100 * float(np.mean(rows["canal"]["free"])), "%",
                                   peer_name=f"DMP + coupling term ({best.split('=')[1]})",
                                   peer_value=100 * float(np.mean(rows[best]["free"])), better="higher"))
    for group, rows in groups.items():
        followers = rows["canal, live"]
        summary.append(summary_row(f"live robots around spheres that reach the end, {group}",
                                   100 * (1.0 - float(np.mean(followers["blocked"]))), "%",
                                   peer_name="reproductions not blocked",
                                   peer_value=100 * (1.0 - float(np.mean(rows["canal"]["blocked"]))),
                                   better="higher"))
    summary.append(summary_row("live step per pose with a 10-obstacle scene, 16 streams", scene_us, "us",
                               peer_name="no scene", peer_value=plain_us))
    write_summary("obstacles", summary)
    doc = __doc__ or ""
    head = doc[doc.index("Sets:"):].strip() if "Sets:" in doc else ""
    note = (f"{'Quick run (--quick): RAIL user 4 only, one generated set per shape. ' if args.quick else ''}"
            f"Wall time {total:.0f} s on a shared 2-core machine; the canal's reproduction with "
            f"obstacles took {np.median(canal_ms):.0f} ms (median) per fold.")
    write_section(head + "\n\n" + note + "\n\n" + text + "\n\n" + live)
    return 0


if __name__ == "__main__":
    sys.exit(main())
