"""Cost of the review recorder (prints a table).

Run: ``.venv/bin/python bench/recording.py`` (``--quick``: fewer fits, a 1-minute stream).

* Fit: the same fits with and without ``recorder.model_fitted`` after each, interleaved in one
  run; the writer thread builds and writes the geometry concurrently, so its GIL share shows up
  in the "with" times.
* Live: a 1 kHz tracker stream on a simulated clock (1 ms per pose), fed one simulated second
  at a time as fast as the loop runs, then waiting for the writer; caller-side cost per pose is
  the time of ``recorder.live`` (enqueue) against the same loop calling a no-op. File sizes
  are per minute of stream time.
* Memory: resident set size before and at the peak of the long stream.
* Uploads (``--uploads``): ``python -m canal_service`` as a user starts it (defaults, info
  logs, live bridge on), with and without recordings, alternated in one run; 1,000-point JSON
  demos from 8 concurrent clients. Reports uploads/s of each and the recordings' cost, then
  checks the recording holds every uploaded demo.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import psutil
from canal_service.recording import Recorder
from canal_service.recording.geometry import model_geometry
from canal_service.recording.mcap_log import McapSegment
from canal_service.recording.rerun_log import RerunSegment

import canal_core

if __package__:
    from bench.common import summary_row, write_summary
else:  # run as a file (python bench/x.py): bench/ is sys.path[0]
    from common import summary_row, write_summary

os.environ.setdefault("XDG_CONFIG_HOME", tempfile.mkdtemp(prefix="canal-bench-rerun-"))


def helix_demos(n: int = 3, samples: int = 300) -> list[np.ndarray]:
    s = np.linspace(0.0, 1.0, samples)
    rng = np.random.default_rng(0)
    return [np.c_[np.cos(4 * s), np.sin(4 * s), s] + 0.03 * rng.standard_normal((samples, 3))
            for _ in range(n)]


def bench_fit(root: Path, demos: list[np.ndarray], repeats: int) -> dict[str, float]:
    rec = Recorder(root, flush_interval_s=1.0)
    without, with_rec, enqueue = [], [], []

    def plain() -> None:
        t0 = time.perf_counter()
        canal_core.fit(demos)
        without.append(time.perf_counter() - t0)

    def recorded(version: int) -> None:
        t0 = time.perf_counter()
        canal = canal_core.fit(demos)
        t1 = time.perf_counter()
        rec.model_fitted("fit", version, canal)
        t2 = time.perf_counter()
        with_rec.append(t2 - t0)
        enqueue.append(t2 - t1)

    try:
        canal_core.fit(demos)  # warm-up
        for version in range(1, repeats + 1):
            # A-B / B-A alternation: neither side always runs first.
            if version % 2:
                plain()
                recorded(version)
            else:
                recorded(version)
                plain()
        rec.export_mcap("fit").unlink()  # everything queued is written before we leave
    finally:
        rec.close()
    base, withr = statistics.median(without), statistics.median(with_rec)
    return {"fit_ms": 1e3 * base, "fit_rec_ms": 1e3 * withr,
            "overhead_pct": 100 * (withr - base) / base,
            "enqueue_us": 1e6 * statistics.median(enqueue),
            "writer_ms_per_model": 1e3 * writer_cost(root / "writer", demos)}


def writer_cost(root: Path, demos: list[np.ndarray], repeats: int = 5) -> float:
    """Seconds the writer thread spends on one model: geometry, both logs, both flushes."""
    canal = canal_core.fit(demos)
    root.mkdir(parents=True)
    times = []
    for k in range(repeats):
        rerun = RerunSegment(root / f"{k}.rrd", "bench", "bench", blueprint=False)
        mcap = McapSegment(root / f"{k}.mcap", time.time_ns())
        t0 = time.perf_counter()
        geo = model_geometry(1, canal)
        rerun.model(time.time_ns(), geo)
        mcap.model(time.time_ns(), geo)
        rerun.flush()
        mcap.flush()
        times.append(time.perf_counter() - t0)
        rerun.close()
        mcap.close()
    return statistics.median(times)


class PeakRss:
    """Samples the process RSS in a thread; ``peak`` after ``stop()``."""

    def __init__(self) -> None:
        self.proc = psutil.Process()
        self.start = self.peak = self.proc.memory_info().rss
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(0.05):
            self.peak = max(self.peak, self.proc.memory_info().rss)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()


def bench_live(root: Path, demos: list[np.ndarray], minutes: float,
               live_max_hz: float | None) -> dict[str, Any]:
    canal = canal_core.fit(demos)
    tracker = canal.tracker()
    path = demos[1]
    targets = [(p, tracker.step(p)) for p in path]  # precomputed: time only the recorder
    n = int(minutes * 60_000)
    rec = Recorder(root, flush_interval_s=0.05, live_max_hz=live_max_hz)
    rss = PeakRss()
    t0 = time.time_ns()

    def noop(*_: Any, **__: Any) -> None:
        return None

    def loop(fn: Any, wait: bool) -> float:
        """Feed 1 s of stream at a time; time only the calls, then let the writer catch up.

        The clock is simulated and the feed runs far faster than real time; waiting between
        blocks keeps the queue from overflowing, as it would not at 1 kHz real time.
        """
        spent = 0.0
        for block in range(0, n, 1000):
            start = time.perf_counter()
            for k in range(block, min(n, block + 1000)):
                p, target = targets[k % len(targets)]
                fn("live", "ur5", p, target, t_ns=t0 + k * 1_000_000)
            spent += time.perf_counter() - start
            while wait and rec.health()["queued"] > 0:
                time.sleep(0.001)
        return spent

    try:
        base = loop(noop, wait=False)
        timed = loop(rec.live, wait=True)
        rec.export_mcap("live").unlink()  # drains the queue; the export is not measured
    finally:
        rec.close()
        rss.stop()
    size = {kind: sum(p.stat().st_size for p in (root / "live").glob(f"seg-*.{kind}"))
            for kind in ("rrd", "mcap")}
    health = rec.health()
    return {
        "poses": n, "minutes": minutes, "hz": live_max_hz or 1000,
        "enqueue_us": 1e6 * (timed - base) / n,
        "rrd_mb_per_min": size["rrd"] / 1e6 / minutes,
        "mcap_mb_per_min": size["mcap"] / 1e6 / minutes,
        "kept": health["live_written"], "decimated": health["decimated"],
        "dropped": health["dropped"],
        "rss_growth_mb": (rss.peak - rss.start) / 1e6,
    }


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _upload_round(recordings: bool, n: int, clients: int, bodies: list[bytes]) -> dict[str, Any]:
    """Start a fresh service, upload ``n`` demos from ``clients`` clients; rate and checks."""
    import httpx

    port, zport = _free_port(), _free_port()
    data = Path(tempfile.mkdtemp(prefix="canal-bench-uploads-"))
    cmd = [sys.executable, "-m", "canal_service", "--port", str(port), "--data-dir", str(data),
           "--zenoh-listen", f"tcp/127.0.0.1:{zport}"]
    if not recordings:
        cmd.append("--no-recordings")
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env=dict(os.environ, RERUN_TELEMETRY_ENABLED="false"))
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                if httpx.get(f"{url}/healthz").status_code in (200, 503):
                    break
            except httpx.TransportError:
                pass
            if time.monotonic() > deadline:
                raise RuntimeError("service did not start")
            time.sleep(0.1)
        httpx.post(f"{url}/skills", json={"name": "up", "dim": 3})

        async def run() -> float:
            limits = httpx.Limits(max_connections=clients)
            async with httpx.AsyncClient(base_url=url, limits=limits, timeout=60) as c:
                queue = list(range(n))

                async def worker() -> None:
                    while queue:
                        i = queue.pop()
                        r = await c.post("/skills/up/demonstrations", content=bodies[i % len(bodies)],
                                         headers={"content-type": "application/json"})
                        assert r.status_code == 201, r.text

                t0 = time.perf_counter()
                await asyncio.gather(*(worker() for _ in range(clients)))
                return time.perf_counter() - t0

        seconds = asyncio.run(run())
        recorded = -1
        if recordings:
            from mcap.reader import make_reader

            r = httpx.get(f"{url}/skills/up/recording.mcap", timeout=600)
            recorded = sum(1 for _ in make_reader(__import__("io").BytesIO(r.content))
                           .iter_messages(topics=["/canal/demos"]))
        return {"rate": n / seconds, "recorded": recorded}
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()


def bench_live_drain(n: int = 20_000) -> list[dict[str, Any]]:
    """Cost per pose row of the recorder's live subscriber (drain thread), real sessions.

    A bridge-like session puts recording batches (16 streams, 0.1 s of a 1 kHz stream each:
    10 rows per stream at the default 100 Hz, 100 when keeping every pose) on the recorder
    key; one drain hands them to the recorder; time per row (a pose and its target).
    """
    import orjson
    import zenoh
    from canal_service import record_batches
    from canal_service.recording.live import LiveOptions, LiveSubscriber

    from canal_protocol import keys as keyspace
    from canal_protocol import wire

    def config(mode: str, listen: list[str], connect: list[str]) -> Any:
        c = zenoh.Config()
        c.insert_json5("mode", orjson.dumps(mode).decode())
        c.insert_json5("scouting/multicast/enabled", "false")
        c.insert_json5("listen/endpoints", orjson.dumps(listen).decode())
        c.insert_json5("connect/endpoints", orjson.dumps(connect).decode())
        return c

    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    bridge = zenoh.open(config("peer", [endpoint], []))
    rows = []
    try:
        for hz in (100.0, None):
            per = 10 if hz else 100
            rec = Recorder(Path(tempfile.mkdtemp(prefix="canal-bench-drain-")), quiet_s=0)
            sub = LiveSubscriber(rec, LiveOptions(listen=(endpoint,), interval_s=3600))
            sub.start()
            time.sleep(1.5)
            key = keyspace.recorder_key("bench", "canal")
            p = [0.1, 0.2, 0.3]
            row = [0, p, None, p, None, 0.5, 0.3, 4, True, False, "ok"]
            batches = max(n // (16 * per), 1)
            for k in range(batches):
                row[0] = time.time_ns()
                bridge.put(key, record_batches.encode_record_batch("bench", k, [
                    ("b", f"r{i}", 100, 100, 0, 0, 100 - per, [row] * per) for i in range(16)]),
                    encoding=wire.JSON_ENCODING)
            time.sleep(1.0)
            t0 = time.perf_counter()
            got = sub.drain()
            dt = time.perf_counter() - t0
            kept = 16 * per * got
            rows.append({"hz": hz or 0, "encoding": "batches", "samples": kept,
                         "us": 1e6 * dt / max(kept, 1)})
            rec.close()
    finally:
        bridge.close()
    return rows


def bench_uploads(n: int, clients: int, rounds: int) -> dict[str, Any]:
    rng = np.random.default_rng(0)
    import orjson

    bodies = [orjson.dumps({"positions": (np.c_[np.linspace(0, 1, 1000), np.sin(
        np.linspace(0, 3, 1000)), np.zeros(1000)] + 0.01 * rng.standard_normal((1000, 3))
                                           ).tolist()}) for _ in range(16)]
    on, off, recorded = [], [], []
    for k in range(rounds):  # alternated (and the order swapped), so both see the same load
        for recordings in ((True, False) if k % 2 == 0 else (False, True)):
            r = _upload_round(recordings, n, clients, bodies)
            if recordings:
                on.append(r["rate"])
                recorded.append(r["recorded"])
            else:
                off.append(r["rate"])
    best_on, best_off = max(on), max(off)
    return {"on": on, "off": off, "best_on": best_on, "best_off": best_off,
            "cost_pct": 100.0 * (1.0 - best_on / best_off), "recorded": recorded, "n": n,
            "clients": clients}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--uploads", action="store_true",
                        help="only the upload rounds through canal serve (with/without recordings)")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--n-uploads", type=int, default=1000)
    parser.add_argument("--live-drain", action="store_true",
                        help="only the cost per pose row of the recorder's live subscriber")
    args = parser.parse_args()
    if args.live_drain:
        print("| recorder live subscriber | kept Hz | pose rows drained | us/row |")
        print("|---|---|---|---|")
        for r in bench_live_drain():
            print(f"| {r['encoding']} | {r['hz'] or 'all':>4} | {r['samples']} | {r['us']:.1f} |")
        return
    if args.uploads:
        up = bench_uploads(args.n_uploads, 8, args.rounds)
        print(f"uploads through python -m canal_service (defaults), {up['n']} x 1,000-point "
              f"JSON demos, {up['clients']} clients, {len(up['on'])} alternated rounds")
        print("| recordings | uploads/s per round | best |")
        print("|---|---|---|")
        print(f"| on  | {', '.join(f'{v:.0f}' for v in up['on'])} | {up['best_on']:.0f} |")
        print(f"| off | {', '.join(f'{v:.0f}' for v in up['off'])} | {up['best_off']:.0f} |")
        print(f"recordings cost {up['cost_pct']:.1f} % of the no-recordings rate (best of each); "
              f"demos in the recording after each round: {up['recorded']} of {up['n']}")
        write_summary("recording", [summary_row(
            "uploads/s with recordings (8 clients)", up["best_on"], "1/s",
            "same run without recordings", up["best_off"], better="higher")])
        return
    demos = helix_demos()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        fit = bench_fit(root / "fit", demos, 10 if args.quick else 40)
        long_minutes = 1.0 if args.quick else 10.0
        live = [bench_live(root / "live100", demos, long_minutes, 100.0),
                bench_live(root / "live1k", demos, 1.0 if not args.quick else 0.25, None)]

    print(f"fit (3 demos x 300 samples, N=200, mesh 6400 vertices), {fit['fit_ms']:.2f} ms alone")
    print(f"| {'measure':44} | {'value':>10} |")
    print(f"|{'-' * 46}|{'-' * 12}|")
    print(f"| {'fit, median, without recorder (ms)':44} | {fit['fit_ms']:10.2f} |")
    print(f"| {'fit + model_fitted, median, with (ms)':44} | {fit['fit_rec_ms']:10.2f} |")
    print(f"| {'overhead on fit (%)':44} | {fit['overhead_pct']:10.1f} |")
    print(f"| {'model_fitted call (enqueue, us)':44} | {fit['enqueue_us']:10.1f} |")
    print(f"| {'writer thread per model: mesh+logs+flush (ms)':44} | "
          f"{fit['writer_ms_per_model']:10.1f} |")
    print()
    print(f"| {'live stream (simulated 1 kHz)':30} | {'kept Hz':>7} | {'poses':>7} | "
          f"{'us/pose':>7} | {'rrd MB/min':>10} | {'mcap MB/min':>11} | {'dropped':>7} | "
          f"{'RSS +MB':>7} |")
    print(f"|{'-' * 32}|{'-' * 9}|{'-' * 9}|{'-' * 9}|{'-' * 12}|{'-' * 13}|{'-' * 9}|{'-' * 9}|")
    for r in live:
        label = f"{r['minutes']:g} min, decimated" if r["hz"] != 1000 else f"{r['minutes']:g} min, every pose"
        print(f"| {label:30} | {r['hz']:7.0f} | {r['poses']:7d} | {r['enqueue_us']:7.2f} | "
              f"{r['rrd_mb_per_min']:10.2f} | {r['mcap_mb_per_min']:11.2f} | "
              f"{r['dropped']:7d} | {r['rss_growth_mb']:7.1f} |")

    write_summary("recording", [
        summary_row("fit + recorder (median)", fit["fit_rec_ms"], "ms",
                    "same fit without recorder", fit["fit_ms"]),
        summary_row("recorder per live pose, caller side (1 kHz)", live[1]["enqueue_us"], "us"),
    ])


if __name__ == "__main__":
    main()
