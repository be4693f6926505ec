"""Live bridge benchmark: pose -> target round trip through real Zenoh on loopback.

Two servers, each in its own process, as deployed:

- the **bridge**: ``python -m canal_service.bridge`` against a SQLite database holding one
  fitted 3-D skill (circle sections, N = 200), recordings on (``--no-recordings`` to drop);
- a **bare echo**: the same receive structure (FIFO channel, one worker thread, a declared
  publisher per stream, not express, as the bridge's) that answers each pose on its target key: it
  publishes the pose's bytes back, no canal work. It is the baseline of the same run.

The client (this process, one Zenoh session) plays N robots: every 1 ms it publishes one
binary pose per stream (positions moving along the canal), and a receiver thread times each
answer by its seq. For N in 1, 4, 16 it reports p50/p99/max round trip, sustained answer
rate and drops (poses without an answer) for echo and bridge, with bridge/echo ratios.
Targets (issue 5): p50 within 1.5x echo and p99 < 1 ms for 1 stream; 16 streams x 1 kHz
with p99 < 5 ms and no drops; the last line says whether they were met.

    python bench/live.py [--quick] [--seconds 5] [--streams 1,4,16] [--no-recordings]
"""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

try:
    from bench.common import summary_row, write_summary
except ImportError:  # run as a file: bench/ is sys.path[0]
    from common import summary_row, write_summary

ROOT = Path(__file__).resolve().parent.parent
SKILL = "bench"
RATE_HZ = 1000.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


# ---- the bare echo server (run as `python bench/live.py --echo ENDPOINT`) -----------------------


def echo_server(endpoint: str) -> int:
    """Answer every ``canal/*/*/pose`` with a fixed target on ``.../target``; no canal work."""
    import signal

    import zenoh

    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("listen/endpoints", f'["{endpoint}"]')
    with zenoh.open(config) as session:
        sub = session.declare_subscriber("canal/*/*/pose", zenoh.handlers.FifoChannel(4096))
        publishers: dict[str, object] = {}

        def work() -> None:
            recv = sub.handler.recv
            while True:
                try:
                    sample = recv()
                except Exception:
                    return
                key = str(sample.key_expr)
                pub = publishers.get(key)
                if pub is None:
                    pub = publishers[key] = session.declare_publisher(
                        key[: -len("pose")] + "target", express=False,
                        congestion_control=zenoh.CongestionControl.BLOCK)
                pub.put(sample.payload.to_bytes(),  # type: ignore[attr-defined]
                        encoding=zenoh.Encoding.APPLICATION_OCTET_STREAM)

        worker = threading.Thread(target=work, daemon=True)
        worker.start()
        stop = threading.Event()
        signal.signal(signal.SIGTERM, lambda *_: stop.set())
        print("echo ready", flush=True)
        try:
            while not stop.wait(0.5):
                pass
        except KeyboardInterrupt:
            pass
        sub.undeclare()
        worker.join(2)
        for pub in publishers.values():
            pub.undeclare()  # type: ignore[attr-defined]
    return 0


# ---- setup ------------------------------------------------------------------------------------


def make_database(data: Path) -> np.ndarray:
    """A skill with 6 noisy arcs fitted (circle, N = 200); returns a path along it."""
    os.environ.setdefault("RERUN_TELEMETRY_ENABLED", "false")
    from canal_service.metrics import Metrics
    from canal_service.schemas import FitRequest, SkillCreate
    from canal_service.service import CanalService
    from canal_service.storage import Database
    from canal_service.validation import check_demonstration

    db = Database(f"sqlite:///{(data / 'canal.sqlite3').resolve()}")
    db.migrate()
    service = CanalService(db, Metrics())
    service.create_skill(SkillCreate(name=SKILL, dim=3))
    rng = np.random.default_rng(0)
    t = np.linspace(0.0, 1.0, 200)
    for _ in range(6):
        off = rng.normal(0.0, 0.02)
        demo = np.column_stack([t, 0.3 * np.sin(np.pi * t) + off,
                                0.1 * t + 0.5 * off * np.cos(np.pi * t)])
        service.add_demonstration(SKILL, check_demonstration(demo, 3), None, "json")
    service.fit(SKILL, FitRequest(n_samples=200))
    canal, *_ = service.load_canal(SKILL, None)
    db.dispose()
    # a slow pass along the canal (2 s per traversal at 1 kHz), slightly off the directrix
    s = np.linspace(0.0, 1.0, 2000)
    idx = np.interp(s, np.linspace(0, 1, canal.n_sections), np.arange(canal.n_sections))
    lo = np.floor(idx).astype(int).clip(0, canal.n_sections - 2)
    frac = (idx - lo)[:, None]
    path = (1 - frac) * canal.directrix[lo] + frac * canal.directrix[lo + 1]
    return np.asarray(path + 0.3 * canal.radii.min() * canal.normals[lo], dtype=np.float64)


def start(cmd: list[str], ready: str, env: dict[str, str]) -> subprocess.Popen[str]:
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=env, cwd=ROOT)
    assert proc.stdout is not None
    line = proc.stdout.readline()
    if ready not in line:
        proc.kill()
        raise RuntimeError(f"{cmd[:3]} did not start: {line!r} {proc.stderr.read() if proc.stderr else ''}")
    return proc


# ---- the client -------------------------------------------------------------------------------


@dataclass
class Run:
    server: str
    streams: int
    sent: int
    received: int
    latencies_us: np.ndarray
    seconds: float

    @property
    def drops(self) -> int:
        return self.sent - self.received

    def pct(self, q: float) -> float:
        return float(np.percentile(self.latencies_us, q)) if self.latencies_us.size else float("nan")

    @property
    def rate(self) -> float:
        return self.received / self.seconds


def drive(endpoint: str, server: str, n_streams: int, seconds: float, path: np.ndarray,
          warmup: float = 0.3) -> Run:
    """N robots at 1 kHz each through one session; latency per answered seq."""
    import zenoh

    sys.path.insert(0, str(ROOT / "clients"))
    from canal_client import wire
    from canal_client.live import client_config

    total = int((seconds + warmup) * RATE_HZ)
    sent_ns = np.zeros((n_streams, total), dtype=np.int64)
    recv_ns = np.zeros((n_streams, total), dtype=np.int64)
    robots = [f"r{i}" for i in range(n_streams)]
    index = {f"canal/{SKILL}/{r}/target": i for i, r in enumerate(robots)}
    payloads = [[wire.encode_pose(k, path[(k + 97 * i) % len(path)],
                                  restart=(k + 97 * i) % len(path) == 0 or k == 0)
                 for k in range(total)] for i in range(n_streams)]
    seq_of = wire.HEADER.unpack_from
    binary = zenoh.Encoding.APPLICATION_OCTET_STREAM
    with zenoh.open(client_config(endpoint)) as session:
        sub = session.declare_subscriber(f"canal/{SKILL}/*/target",
                                         zenoh.handlers.FifoChannel(65536))
        pubs = [session.declare_publisher(f"canal/{SKILL}/{r}/pose", encoding=binary,
                                          express=False,
                                          congestion_control=zenoh.CongestionControl.BLOCK)
                for r in robots]
        deadline = time.monotonic() + 5
        while not all(p.matching_status for p in pubs) and time.monotonic() < deadline:
            time.sleep(0.005)
        time.sleep(0.1)

        def receive() -> None:
            recv = sub.handler.recv
            clock = time.perf_counter_ns
            while True:
                try:
                    sample = recv()
                except Exception:
                    return
                now = clock()
                i = index.get(str(sample.key_expr))
                data = sample.payload.to_bytes()
                if i is None:
                    continue
                seq = seq_of(data)[4]  # the pose's own bytes (echo) or the target: same header
                if 0 <= seq < total and recv_ns[i, seq] == 0:
                    recv_ns[i, seq] = now

        receiver = threading.Thread(target=receive, daemon=True)
        receiver.start()
        clock = time.perf_counter_ns
        t0 = time.perf_counter()
        period = 1.0 / RATE_HZ
        for k in range(total):
            wait = t0 + k * period - time.perf_counter()
            if wait > 0:
                time.sleep(wait)
            for i in range(n_streams):
                sent_ns[i, k] = clock()
                pubs[i].put(payloads[i][k])
        time.sleep(0.5)  # let the last answers arrive
        sub.undeclare()
        receiver.join(2)
        for p in pubs:
            p.undeclare()
    first = int(warmup * RATE_HZ)
    s, r = sent_ns[:, first:], recv_ns[:, first:]
    got = r > 0
    lat = (r[got] - s[got]) / 1e3
    return Run(server, n_streams, int(s.size), int(got.sum()), lat, seconds)


# ---- main -------------------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python bench/live.py", description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="1 s per configuration")
    parser.add_argument("--seconds", type=float, default=None, help="measured seconds per run")
    parser.add_argument("--streams", default="1,4,16")
    parser.add_argument("--no-recordings", action="store_true")
    parser.add_argument("--echo", metavar="ENDPOINT", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.echo:
        return echo_server(args.echo)
    seconds = args.seconds or (1.0 if args.quick else 5.0)
    counts = [int(n) for n in args.streams.split(",")]
    # OpenBLAS worker threads spin after each call and starve Zenoh's I/O threads on a small
    # machine; the tracker's matrices are tiny, so one BLAS thread is the deployment setting.
    env = dict(os.environ, RERUN_TELEMETRY_ENABLED="false", CANAL_LOG_LEVEL="warning",
               OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1",
               PYTHONPATH=os.pathsep.join([str(ROOT), str(ROOT / "service"),
                                           str(ROOT / "clients"),
                                           os.environ.get("PYTHONPATH", "")]))
    with tempfile.TemporaryDirectory(prefix="canal-bench-live-") as tmp:
        data = Path(tmp)
        path = make_database(data)
        bridge_ep = f"tcp/127.0.0.1:{free_port()}"
        echo_ep = f"tcp/127.0.0.1:{free_port()}"
        cmd = [sys.executable, "-m", "canal_service.bridge", "--data-dir", str(data),
               "--zenoh-listen", bridge_ep]
        if args.no_recordings:
            cmd.append("--no-recordings")
        bridge = start(cmd, "ready", env)
        echo = start([sys.executable, str(Path(__file__).resolve()), "--echo", echo_ep],
                     "ready", env)
        runs: list[tuple[Run, Run]] = []
        try:
            for n in counts:
                e = drive(echo_ep, "echo", n, seconds, path)
                b = drive(bridge_ep, "bridge", n, seconds, path)
                runs.append((e, b))
                print(f"  {n:>2} streams: echo p50 {e.pct(50):.0f} us, bridge p50 "
                      f"{b.pct(50):.0f} us, bridge drops {b.drops}", file=sys.stderr)
        finally:
            for proc in (bridge, echo):
                proc.terminate()
                try:
                    proc.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    proc.kill()
    ok = True
    print(f"\nLive round trip, pose -> target, loopback, {RATE_HZ:.0f} Hz per stream, "
          f"{seconds:g} s per run (recordings {'off' if args.no_recordings else 'on'})\n")
    print("| streams | server | p50 us | p99 us | max us | answers/s | drops | p50 / echo "
          "| p99 / echo |")
    print("|---|---|---|---|---|---|---|---|---|")
    summary = []
    for e, b in runs:
        for r in (e, b):
            ratio50 = r.pct(50) / e.pct(50)
            ratio99 = r.pct(99) / e.pct(99)
            print(f"| {r.streams} | {r.server} | {r.pct(50):.0f} | {r.pct(99):.0f} | "
                  f"{r.latencies_us.max() if r.latencies_us.size else float('nan'):.0f} | "
                  f"{r.rate:.0f} | {r.drops} | {ratio50:.2f} | {ratio99:.2f} |")
        if b.streams == 1:
            ok &= b.pct(50) <= 1.5 * e.pct(50) and b.pct(99) < 1000.0
        if b.streams == 16:
            ok &= b.pct(99) < 5000.0 and b.drops == 0
        summary.append(summary_row(f"live round trip p50, {b.streams} stream(s)",
                                   b.pct(50) / 1e3, "ms", "bare Zenoh echo", e.pct(50) / 1e3))
        summary.append(summary_row(f"live round trip p99, {b.streams} stream(s)",
                                   b.pct(99) / 1e3, "ms", "bare Zenoh echo", e.pct(99) / 1e3))
    print("\nTargets: 1 stream p50 <= 1.5x echo and p99 < 1 ms; 16 streams p99 < 5 ms, no drops: "
          + ("met" if ok else "MISSED"))
    write_summary("live", summary)
    return 0  # a benchmark reports; missing a target is a finding, not a failure


if __name__ == "__main__":
    raise SystemExit(main())
