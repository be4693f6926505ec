"""First pose of a new skill: its answer time, and how long other robots' answers stall.

A bridge process as ``canal serve`` starts it (``python -m canal_service.bridge
--supervised``, fit notices on stdin) runs against a SQLite file with one busy skill and K
skills fitted after the bridge started. This process plays R robots of the busy skill at
~1 kHz each (JSON poses, one Zenoh session) and times every answer. For each new skill it
then writes the skill's fit notice on the bridge's stdin (as ``canal serve`` does), waits
0.2 s, puts the skill's first pose and times its answer. Two bridges, the same drive:

- ``load at first pose``: ``--zenoh-preload-max 0``, today's behaviour before preloading:
  the notice of a skill not in use is ignored and the worker loads the model (database
  read, canal decoded, tracker geometry and bank tables built) when the first pose comes;
- ``preload``: the default, the thread that read the notice loads it.

Reported per bridge: the first pose's round trip (median and max over the K skills); the
worst round trip of the busy robots' poses put within the first pose's window (put 2 ms
before it up to 5 ms after its answer) and within the notice's 0.2 s, as medians over the K
events; the same worst within 0.2 s when nothing happens (after each first answer) and the busy
robots' p50/p99 outside those windows (the same-run yardsticks). Wall-clock:
on a shared machine compare the two bridges' ratios, not the absolute figures.

It also times, in this process and in CPU time (``time.process_time``), loading one model
with a cold cache against one tracker step of one pose of the busy skill.

    python bench/first_pose.py [--skills 8] [--robots 4] [--n-samples 200]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import orjson
import zenoh

from canal_protocol import keys as keyspace
from canal_protocol import wire
from canal_protocol.schemas import DemonstrationIn, FitRequest, SkillCreate

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))
from canal_testing import arc_demo, free_port  # noqa: E402

BUSY = "busy"
PREFIX = "firstpose"


def add_skill(service: Any, name: str, n_samples: int) -> None:
    service.create_skill(SkillCreate(name=name, description="", dim=3))
    for j in range(4):
        demo = arc_demo(j, 300, 3, seed=len(name), spread=0.03)
        service.add_json_demonstration(name, DemonstrationIn(positions=demo.tolist()))
    service.fit(name, FitRequest(n_samples=n_samples))


def client_config(endpoint: str) -> zenoh.Config:
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("connect/endpoints", orjson.dumps([endpoint]).decode())
    return config


def drive(label: str, data: Path, url: str, news: list[str], preload_max: int, robots: int,
          directrix: np.ndarray, prepare: Callable[[], dict[str, list[float]]]
          ) -> dict[str, Any]:
    """One bridge process, the drive, the figures. ``prepare`` (called once the bridge has
    started and read the database) fits the new skills and gives each one's first pose."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1",
               RERUN_TELEMETRY_ENABLED="false")
    proc = subprocess.Popen(
        [sys.executable, "-m", "canal_service.bridge", "--supervised", "--data-dir", str(data),
         "--database-url", url, "--zenoh-listen", endpoint, "--zenoh-prefix", PREFIX,
         "--no-recordings", "--zenoh-preload-max", str(preload_max), "--log-level", "warning"],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env)
    assert proc.stdin is not None and proc.stdout is not None
    ready = proc.stdout.readline().decode()
    assert ready.startswith("canal bridge ready"), ready
    out = proc.stdout
    threading.Thread(target=lambda: [None for _ in out], daemon=True).start()
    time.sleep(0.5)  # its start-up preload has listed the skills: the new ones come later
    starts = prepare()
    sent: dict[tuple[str, int], float] = {}
    got: dict[tuple[str, int], float] = {}
    answered = threading.Condition()

    def on_target(sample: Any) -> None:
        now = time.perf_counter()
        found = keyspace.stream_of(str(sample.key_expr), PREFIX, keyspace.TARGET)
        body = orjson.loads(sample.payload.to_bytes())
        if found is None or body.get("status") != "ok":
            return
        with answered:
            got[(found[0] + "/" + found[1], int(body["seq"]))] = now
            answered.notify_all()

    stop = threading.Event()
    with zenoh.open(client_config(endpoint)) as session:
        sub = session.declare_subscriber(f"{PREFIX}/*/*/target", on_target)
        enc = zenoh.Encoding.APPLICATION_JSON
        pubs = [session.declare_publisher(keyspace.keys(BUSY, f"r{i}", PREFIX).pose,
                                          encoding=enc) for i in range(robots)]
        deadline = time.monotonic() + 10
        while not all(p.matching_status.matching for p in pubs) and time.monotonic() < deadline:
            time.sleep(0.01)

        def busy() -> None:
            seq = 0
            n = len(directrix)
            while not stop.is_set():
                k = 20 + (seq // 40) % (n - 40)  # slowly along the canal, then again
                for i, pub in enumerate(pubs):
                    sent[(f"{BUSY}/r{i}", seq)] = time.perf_counter()
                    pub.put(wire.encode_pose_json(seq, directrix[k], restart=seq == 0))
                seq += 1
                time.sleep(0.001)

        sender = threading.Thread(target=busy, daemon=True)
        sender.start()
        time.sleep(1.0)  # streams warm
        events = []
        for skill in news:
            t_notice = time.perf_counter()
            proc.stdin.write(orjson.dumps({"fit": skill, "version": 1}) + b"\n")
            proc.stdin.flush()
            time.sleep(0.2)
            key = (f"{skill}/first", 0)
            start = starts[skill]
            t_put = time.perf_counter()
            sent[key] = t_put
            session.put(keyspace.keys(skill, "first", PREFIX).pose,
                        wire.encode_pose_json(0, start, restart=True), encoding=enc)
            with answered:
                answered.wait_for(lambda key=key: key in got, timeout=10)  # type: ignore[misc]
            events.append((t_notice, t_put, got.get(key, float("nan"))))
            time.sleep(0.2)
        stop.set()
        sender.join()
        time.sleep(0.2)
        sub.undeclare()
    proc.stdin.close()
    proc.wait(timeout=20)
    busy_rtt = [(s, got[k] - s) for k, s in sent.items() if k[0].startswith(BUSY) and k in got]
    first = [1e3 * (t_ans - t_put) for _t_n, t_put, t_ans in events]
    at_first, at_notice, at_quiet = [], [], []
    windows = []

    def worst(window: tuple[float, float]) -> float:
        return 1e3 * max((r for s, r in busy_rtt if window[0] <= s <= window[1]),
                         default=float("nan"))

    for t_notice, t_put, t_ans in events:
        w_first = (t_put - 0.002, t_ans + 0.005)
        w_notice = (t_notice, t_notice + 0.2)
        windows += [w_first, w_notice]
        at_first.append(worst(w_first))
        at_notice.append(worst(w_notice))
        at_quiet.append(worst((t_ans + 0.01, t_ans + 0.19)))  # nothing happens then
    quiet = sorted(1e3 * r for s, r in busy_rtt if not any(a <= s <= b for a, b in windows))
    return {"label": label, "first_med": statistics.median(first), "first_max": max(first),
            "others_at_first": statistics.median(at_first),
            "others_at_notice": statistics.median(at_notice),
            "others_quiet": statistics.median(at_quiet),
            "p50": quiet[len(quiet) // 2], "p99": quiet[int(0.99 * (len(quiet) - 1))],
            "answered": len(busy_rtt) / max(1, sum(1 for k in sent if k[0].startswith(BUSY)))}


def cpu_costs(url: str, news: list[str]) -> tuple[float, float]:
    """CPU ms of one model load (cold cache) and of one single-pose tracker step."""
    from canal_service.bridge.config import BridgeOptions
    from canal_service.bridge.models import ModelTable
    from canal_service.metrics import Metrics
    from canal_service.service import CanalService
    from canal_service.storage import Database

    db = Database(url)
    try:
        table = ModelTable(CanalService(db, Metrics(), cache_size=0), BridgeOptions())
        started = time.process_time()
        for skill in news:
            table.load(skill)
        load_ms = 1e3 * (time.process_time() - started) / len(news)
        entry = table.load(BUSY)
        assert entry.bank is not None
        bank, slot = entry.bank, entry.bank.add()
        points = np.asarray(entry.canal.directrix)
        started = time.process_time()
        for k in range(2000):
            bank.step([slot], points[20 + (k // 10) % 100][None, :])
        step_ms = 1e3 * (time.process_time() - started) / 2000
    finally:
        db.dispose()
    return load_ms, step_ms


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--skills", type=int, default=8)
    parser.add_argument("--robots", type=int, default=4)
    parser.add_argument("--n-samples", type=int, default=200)
    args = parser.parse_args(argv)
    from canal_service.metrics import Metrics
    from canal_service.service import CanalService
    from canal_service.storage import Database

    with tempfile.TemporaryDirectory(prefix="canal-first-pose-") as tmp:
        data = Path(tmp)
        results = []
        for label, preload_max in (("load at first pose", 0), ("preload", 64)):
            url = f"sqlite:///{data / (str(preload_max) + '.sqlite3')}"
            db = Database(url)
            db.migrate()
            service = CanalService(db, Metrics())
            add_skill(service, BUSY, args.n_samples)
            directrix = np.asarray(service.load_canal(BUSY, None)[0].directrix)
            news = [f"new{i}" for i in range(args.skills)]

            def fit_news(service: Any = service, news: list[str] = news
                         ) -> dict[str, list[float]]:
                starts = {}
                for skill in news:
                    add_skill(service, skill, args.n_samples)
                    starts[skill] = np.asarray(
                        service.load_canal(skill, None)[0].directrix[3]).tolist()
                return starts

            results.append(drive(label, data, url, news, preload_max, args.robots, directrix,
                                 fit_news))
            if preload_max:
                load_ms, step_ms = cpu_costs(url, news)
            db.dispose()
    print(f"\nfirst pose of a new skill, {args.robots} busy robots at ~1 kHz, {args.skills} "
          f"skills, N = {args.n_samples} (wall ms; shared machine: compare ratios)\n")
    print("| bridge | first pose med / max | others' worst at first pose | others' worst "
          "during notice | others' worst in a quiet 0.2 s | busy p50 / p99 | answered |")
    print("|---|---|---|---|---|---|---|")
    for r in results:
        print(f"| {r['label']} | {r['first_med']:.2f} / {r['first_max']:.2f} | "
              f"{r['others_at_first']:.2f} ({r['others_at_first'] / r['p50']:.1f}x p50) | "
              f"{r['others_at_notice']:.2f} ({r['others_at_notice'] / r['p50']:.1f}x p50) | "
              f"{r['others_quiet']:.2f} ({r['others_quiet'] / r['p50']:.1f}x p50) | "
              f"{r['p50']:.2f} / {r['p99']:.2f} | {100 * r['answered']:.1f} % |")
    before, after = results
    print(f"\nfirst pose, preload / load at first pose: "
          f"{after['first_med'] / before['first_med']:.2f}x (median); others' worst at the "
          f"first pose: {after['others_at_first'] / before['others_at_first']:.2f}x")
    print(f"CPU: one model load (cold cache) {load_ms:.2f} ms = {load_ms / step_ms:.0f} "
          f"single-pose tracker steps ({1e3 * step_ms:.1f} us each)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
