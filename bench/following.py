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

Through ``canal serve``: the same robot, but its poses go as JSON over Zenoh on loopback to
``canal serve`` with its defaults (recordings on), which fitted the group's demonstrations
from a REST upload, and its targets come back the same way (the first
:data:`SERVE_STARTS` starts of each group of RAIL, the UR5e reaches and the generated logs).
The yardstick is the in-process tracker above, from the same starts in the same run.
"""

from __future__ import annotations

import argparse
import re
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
#: starts per group followed through canal serve
SERVE_STARTS = 12


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


def served_group(name: str, sets: dict, port: int, endpoint: str) -> dict:
    """The first :data:`SERVE_STARTS` starts of a group, followed through ``canal serve``:
    each set is a skill uploaded and fitted over REST, each start a robot streaming JSON poses
    over Zenoh. Beside them, the in-process tracker from the same starts."""
    import httpx
    from canal_client.live import PoseStreamer

    done = starts = local_done = 0
    ratios: list[float] = []
    client = httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=300.0)
    for k, demos in enumerate(sets.values()):
        if starts >= SERVE_STARTS:
            break
        arrays = [d.positions for d in demos]
        skill = f"follow-{re.sub('[^a-z0-9]+', '-', name.lower()).strip('-')[:40]}-{k}"
        client.post("/skills", json={"name": skill, "dim": int(arrays[0].shape[1])}).raise_for_status()
        for a in arrays:
            client.post(f"/skills/{skill}/demonstrations", json={"positions": a.tolist()}).raise_for_status()
        client.post(f"/skills/{skill}/fit", json={}).raise_for_status()
        routes = fit_routes(arrays)
        time.sleep(1.0)  # the bridge hears of the new model
        for j, demo in enumerate(arrays[: SERVE_STARTS - starts]):
            start = demo[0]
            with PoseStreamer(skill, robot=f"r{j}", endpoint=endpoint, encoding="json") as robot:
                x = start.copy()
                path, reached = [x.copy()], False
                answer = robot.wait_for(robot.send(x.tolist(), restart=True), 5.0)
                for _ in range(MAX_POSES):
                    if answer is None or answer.target is None:
                        break
                    if answer.done:
                        reached = True
                        break
                    x = x + GAIN * (np.asarray(answer.target) - x)
                    path.append(x.copy())
                    answer = robot.wait_for(robot.send(x.tolist()), 5.0)
            local, local_reached = followed(routes.canal_for(routes.choose(start)), start)
            starts += 1
            done += reached
            local_done += local_reached
            yardstick = dtw_to(local, demo)
            if yardstick > 0.0:
                ratios.append(dtw_to(np.array(path), demo) / yardstick)
    client.close()
    return {"starts": starts, "done": done, "local_done": local_done,
            "ratio": float(np.median(ratios)) if ratios else float("nan")}


def serve_rows(quick: bool) -> tuple[list[str], list[dict]]:
    """Rows of the through-canal-serve table, and their headline figures."""
    import tempfile

    if __package__:
        from bench.live import free_port, start_serve, stop
    else:
        from live import free_port, start_serve, stop

    rows, summary = [], []
    with tempfile.TemporaryDirectory(prefix="canal-following-") as data:
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        proc, port = start_serve(Path(data), endpoint)
        try:
            for name, sets, _unit in plan_groups({"rail", "ur5e", "raw3d"}, quick, 1, None):
                t0 = time.perf_counter()
                r = served_group(name, sets, port, endpoint)
                share = r["done"] / max(r["starts"], 1)
                local = r["local_done"] / max(r["starts"], 1)
                rows.append(f"| {name} | {r['starts']} | {r['done']} | {100 * share:.0f} % | "
                            f"{100 * local:.0f} % | {r['ratio']:.3f} | {time.perf_counter() - t0:.0f} |")
                print(rows[-1], flush=True)
                summary.append(summary_row(
                    f"starts from which a robot following canal serve's live targets reaches the end, {name}",
                    100 * share, "%", "the in-process tracker", 100 * local, better="higher"))
        finally:
            stop(proc)
    return rows, summary


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
    served, served_summary = serve_rows(args.quick)
    served_table = "\n".join([
        "| group (through canal serve) | starts | reached the end | share | in-process tracker, same starts | "
        "median DTW: through canal serve / in-process | s |",
        "|---|---:|---:|---:|---:|---:|---:|", *served])
    print(served_table)
    summary += served_summary
    write_section(f"A first-order robot (each pose {int(100 * GAIN)} % of the way to its target) follows "
                  f"the live tracker (lookahead {LOOKAHEAD}, the compiled kernel) from every "
                  "demonstration's first point; the yardstick is the offline reproduction from the "
                  "same start. DTW to the demonstration that started there, both paths resampled "
                  f"by arc length. Wall time {time.perf_counter() - started:.0f} s.\n\n" + table
                  + "\n\nThe same robot through `canal serve` with its defaults (JSON poses over Zenoh on "
                  f"loopback, the model fitted from a REST upload), the first {SERVE_STARTS} starts of "
                  "each group; the yardstick is the in-process tracker from the same starts.\n\n"
                  + served_table)
    write_summary("following", summary)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
