"""Following live targets: a robot on the live tracker, against the offline reproduction.

Usage: ``python bench/following.py [--quick]``; its section of BENCHMARKS.md:
``python -m bench --only following --write``.

The groups of ``bench/quality.py`` (RAIL by task and start region, LASA's 30 shapes and its four
multi-route shapes, the UR5e reaches, generated raw 3-D logs; the same preprocessed arrays).
Each group is fitted with the service's defaults (``fit_routes``), and from every
demonstration's first point:

* a first-order robot follows the answers of the tracker the live bridge steps with (a
  ``TrackerBank`` on the route the start chooses, lookahead 2, the compiled kernel): each pose
  moves 30 % of the way to its target, for at most 4,000 poses;
* the offline reproduction (``reproduce_detailed``) from the same start is the yardstick.

Reported per group: the share of starts from which the robot reaches the end (``done``), and
the median DTW from the followed path to the demonstration that started there, divided by the
offline reproduction's (both resampled to 200 points by arc length): 1 means the live robot
goes where the reproduction says it would.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from canal_core.metrics import resampled_by_arc_length  # noqa: E402
from canal_core.routes import fit_routes  # noqa: E402
from canal_core.tracker_bank import TrackerBank  # noqa: E402
from canal_core.tracker_kernel import compile_step_rows  # noqa: E402
from canal_core.warping import dtw_distance  # noqa: E402

if __package__:
    from bench.common import summary_row, write_section, write_summary
    from bench.quality import plan_groups
else:
    from common import summary_row, write_section, write_summary
    from quality import plan_groups

GAIN = 0.3
MAX_POSES = 4000
LOOKAHEAD = 2


def followed(canal: object, start: np.ndarray) -> tuple[np.ndarray, bool]:
    """The path of a first-order robot following the live tracker from ``start``, and whether
    it reached the end."""
    bank = TrackerBank(canal.tracker_geometry(), LOOKAHEAD)  # type: ignore[attr-defined]
    slot = bank.add()
    bank.reset(slot, int(canal.reproduce_detailed(start).section_index))  # type: ignore[attr-defined]
    x = start.copy()
    path = [x.copy()]
    for _ in range(MAX_POSES):
        batch = bank.step([slot], x[None, :])
        if bool(batch.done[0]):
            return np.array(path), True
        x = x + GAIN * (batch.target[0] - x)
        path.append(x.copy())
    return np.array(path), False


def dtw_to(path: np.ndarray, demo: np.ndarray) -> float:
    return float(dtw_distance(resampled_by_arc_length(path, 200), resampled_by_arc_length(demo, 200)))


def run_group(sets: dict) -> dict:
    done, ratios, starts = 0, [], 0
    for demos in sets.values():
        arrays = [d.positions for d in demos]
        routes = fit_routes(arrays)
        for demo in arrays:
            start = demo[0]
            canal = routes.canal_for(routes.choose(start))
            path, reached = followed(canal, start)
            offline = canal.reproduce_detailed(start).positions
            starts += 1
            done += reached
            yardstick = dtw_to(offline, demo)
            if yardstick > 0.0:
                ratios.append(dtw_to(path, demo) / yardstick)
    return {"starts": starts, "done": done, "ratio": float(np.median(ratios)) if ratios else float("nan")}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="one set per group, fewer groups")
    args = parser.parse_args(argv)
    assert compile_step_rows() is not None, "numba is a dependency of the bench install"
    only = {"rail", "multi", "ur5e", "raw3d"} if args.quick else {"rail", "lasa", "multi", "ur5e", "raw3d"}
    rows, summary = [], []
    started = time.perf_counter()
    for name, sets, _unit in plan_groups(only, args.quick, 1 if args.quick else 3, None):
        t0 = time.perf_counter()
        r = run_group(sets)
        share = r["done"] / max(r["starts"], 1)
        rows.append(f"| {name} | {r['starts']} | {r['done']} | {100 * share:.0f} % | {r['ratio']:.3f} | "
                    f"{time.perf_counter() - t0:.0f} |")
        print(rows[-1], flush=True)
        summary.append(summary_row(f"starts from which a robot following live targets reaches the end, {name}",
                                   100 * share, "%", "offline reproduction", 100.0, better="higher"))
        summary.append(summary_row(f"median DTW of the followed path / the offline reproduction's, {name}",
                                   r["ratio"], "", "offline reproduction", 1.0))
    table = "\n".join([
        "| group | starts | reached the end | share | median DTW: followed / offline | s |",
        "|---|---:|---:|---:|---:|---:|", *rows])
    print(table)
    write_section(f"A first-order robot (each pose {int(100 * GAIN)} % of the way to its target) follows "
                  f"the live tracker (lookahead {LOOKAHEAD}, the compiled kernel) from every "
                  "demonstration's first point; the yardstick is the offline reproduction from the "
                  "same start. DTW to the demonstration that started there, both paths resampled "
                  f"by arc length. Wall time {time.perf_counter() - started:.0f} s.\n\n" + table)
    write_summary("following", summary)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
