"""Service benchmark over real HTTP: uploads, fits and reproductions.

Starts the service the way a user does, ``canal serve`` with its defaults (recordings on,
the live bridge on, info logs to the terminal; here to a log file), on a free loopback port
with a fresh data folder, and drives it with a concurrent httpx client:

1. uploads of 1,000-point JSON demonstrations at 1 and at 8 clients, then a check that every
   one is stored (count, and the SHA-256 checksum of each upload's positions);
2. fits: one over all uploaded demos, then repeated fits of a 10 x 1,000-point skill;
3. 1,000 reproductions against the fitted model.

Then the uploads again on ``canal serve --no-recordings`` (the second row: what recordings
cost, measured in the same run), and the upload path taken apart in this process: server
CPU (process time) per upload for each stage (parse, validate, prepare, DB insert and commit,
recorder enqueue, recorder write), meaningful even on a busy machine where rates are not.
The HTTP rows also give the recorder's writer-thread CPU spent during the burst (``rec cpu
ms``, from ``/healthz``), and a per-thread table says where the server's CPU went during each
8-client burst: the event loop (HTTP, routing, the response), the upload lane
(``canal-upload-*``: parse, checks, preparation, insert), the recorder's writer, and the
rest (AnyIO's pool, Rerun's and Zenoh's threads), read from ``/proc/PID/task``.

The client is honest but cheap: every upload body is a distinct demo, serialised once before
the clock starts (so the client's CPU, on the same 2 cores, goes to HTTP only), and every
stored demo is checked against the SHA-256 of what was sent. Prints uploads/s and p50/p99
latency with the service's targets (on a 2-core machine: uploads >= 200/s at 8
clients with the defaults and recordings costing <= 10 % of the ``--no-recordings`` rate,
fit p99 < 100 ms for 10 x 1,000, reproduction p99 < 20 ms) and exits 1 when a target or the
storage check fails. ``--quick`` runs a tenth of the work.

    python bench/service.py [--quick] [--concurrency 8]
"""

from __future__ import annotations

import argparse
import asyncio
import hashlib
import os
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import httpx
import numpy as np
import orjson

if __package__:
    from bench.common import summary_row, write_summary
else:  # run as a file (python bench/x.py): bench/ is sys.path[0]
    from common import summary_row, write_summary

ROOT = Path(__file__).resolve().parent.parent


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def demo(j: int, n: int, rng: np.random.Generator) -> np.ndarray:
    """A noisy arc, different per demo."""
    t = np.linspace(0.0, 1.0, n)
    off = rng.normal(0.0, 0.02)
    return np.column_stack([
        t,
        0.3 * np.sin(np.pi * t) + off + 0.002 * rng.standard_normal(n),
        0.1 * t + 0.5 * off * np.cos(np.pi * t) + 0.002 * rng.standard_normal(n),
    ])


def checksum(positions: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(positions, dtype="<f8").tobytes()).hexdigest()


def thread_cpu(pid: int | None) -> dict[int, tuple[str, float]]:
    """(OS thread name, user + system CPU seconds) of every thread of ``pid``, by thread id
    (empty where /proc is missing)."""
    out: dict[int, tuple[str, float]] = {}
    if pid is None:
        return out
    tick = os.sysconf("SC_CLK_TCK")
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            name = (task / "comm").read_text().strip()
            fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:  # the thread ended meanwhile
            continue
        out[int(task.name)] = (name, (int(fields[11]) + int(fields[12])) / tick)
    return out


def thread_groups(pid: int, before: dict[int, tuple[str, float]],
                  after: dict[int, tuple[str, float]]) -> dict[str, float]:
    """CPU seconds spent between two :func:`thread_cpu` snapshots, by kind of thread.

    The event loop is the main thread (uvicorn runs it there); lane threads carry their
    name to the OS (``canal-upload-0``, ...); the recorder's writer is ``canal-recorder``.
    """
    groups: dict[str, float] = {}
    for tid, (name, cpu) in after.items():
        spent = cpu - before.get(tid, (name, 0.0))[1]
        if tid == pid:
            kind = "event loop"
        elif name.startswith("canal-upload"):
            kind = "upload lane"
        elif name.startswith("canal-recorder"):
            kind = "recorder writer"
        else:
            kind = "other threads"
        groups[kind] = groups.get(kind, 0.0) + spent
    return groups


def cpu_seconds(pid: int | None) -> float:
    """User + system CPU time of process ``pid`` so far (NaN where /proc is missing)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return float("nan")
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


@dataclass
class Row:
    name: str
    count: int
    seconds: float
    latencies: list[float]
    target: str = ""
    ok: bool | None = None
    server_cpu: float = float("nan")  # server CPU seconds spent on the step
    recorder_cpu: float = float("nan")  # of which the recorder's writer thread
    threads: dict[str, float] | None = None  # server CPU seconds by kind of thread

    @property
    def rec_ms(self) -> float:
        return self.recorder_cpu / self.count * 1000 if self.count else float("nan")

    @property
    def cpu_ms(self) -> float:
        return self.server_cpu / self.count * 1000 if self.count else float("nan")

    @property
    def rate(self) -> float:
        return self.count / self.seconds if self.seconds else float("nan")

    def pct(self, q: float) -> float:
        return float(np.percentile(self.latencies, q)) * 1000 if self.latencies else float("nan")


async def timed(client: httpx.AsyncClient, method: str, url: str, **kw: object
                ) -> tuple[httpx.Response, float]:
    t0 = time.perf_counter()
    r = await client.request(method, url, **kw)  # type: ignore[arg-type]
    return r, time.perf_counter() - t0


async def run_many(n: int, concurrency: int, make: object) -> tuple[list[object], float]:
    """Run ``make(i)`` coroutines for i < n, at most ``concurrency`` at once."""
    sem = asyncio.Semaphore(concurrency)

    async def one(i: int) -> object:
        async with sem:
            return await make(i)  # type: ignore[operator]

    t0 = time.perf_counter()
    results = await asyncio.gather(*(one(i) for i in range(n)))
    return list(results), time.perf_counter() - t0


async def writer_cpu(client: httpx.AsyncClient) -> float:
    """CPU seconds of the recorder's writer thread so far (0 with recordings off)."""
    recorder = (await client.get("/healthz")).json().get("recorder", {})
    return float(recorder.get("writer_cpu_s", 0.0))


async def uploads(client: httpx.AsyncClient, skill: str, n: int, n_points: int,
                  concurrency: int, rng: np.random.Generator, label: str,
                  problems: list[str], pid: int | None = None) -> Row:
    """``n`` uploads of ``n_points``-point JSON demos at ``concurrency`` clients, all checked."""
    await client.post("/skills", json={"name": skill, "dim": 3})
    demos = [demo(j, n_points, rng) for j in range(n)]
    bodies = [orjson.dumps({"positions": d, "label": f"d{j}"},
                           option=orjson.OPT_SERIALIZE_NUMPY) for j, d in enumerate(demos)]
    headers = {"content-type": "application/json"}

    async def upload(i: int) -> tuple[httpx.Response, float]:
        return await timed(client, "POST", f"/skills/{skill}/demonstrations",
                           content=bodies[i], headers=headers)

    rec0 = await writer_cpu(client)
    cpu0 = cpu_seconds(pid)
    threads0 = thread_cpu(pid)
    results, seconds = await run_many(n, concurrency, upload)
    cpu = cpu_seconds(pid) - cpu0
    threads = thread_groups(pid, threads0, thread_cpu(pid)) if pid is not None else None
    rec = await writer_cpu(client) - rec0
    bad = [r for r, _ in results if r.status_code != 201]  # type: ignore[misc]
    if bad:
        problems.append(f"{len(bad)} uploads failed, first: {bad[0].status_code} {bad[0].text}")
    row = Row(f"upload {label} x{concurrency}", n, seconds,
              [lat for _, lat in results],  # type: ignore[misc]
              ">= 200/s" if concurrency > 1 else "", server_cpu=cpu, recorder_cpu=rec,
              threads=threads)
    if concurrency > 1:
        row.ok = row.rate >= 200
    # every upload stored: count and checksums
    stored: list[str] = []
    offset = 0
    while True:
        page = (await client.get(f"/skills/{skill}/demonstrations",
                                 params={"offset": offset, "limit": 1000})).json()
        stored += [item["checksum"] for item in page["items"]]
        offset += len(page["items"])
        if not page["items"] or offset >= page["total"]:
            break
    expected = sorted(checksum(d) for d in demos)
    if len(stored) != n or sorted(stored) != expected:
        problems.append(f"{skill}: storage check failed: {len(stored)} stored of {n}, "
                        f"{len(set(stored) & set(expected))} checksums match")
    return row


async def bench(url: str, label: str, n_uploads: int, n_points: int, n_fits: int,
                n_repro: int, concurrency: int, repro_concurrency: int, pid: int | None = None
                ) -> tuple[list[Row], list[str]]:
    rng = np.random.default_rng(0)
    problems: list[str] = []
    rows: list[Row] = []
    limits = httpx.Limits(max_connections=concurrency, max_keepalive_connections=concurrency)
    async with httpx.AsyncClient(base_url=url, timeout=120, limits=limits) as client:
        rows.append(await uploads(client, "bench1", max(n_uploads // 5, 20), n_points, 1, rng,
                                  label, problems, pid))
        rows.append(await uploads(client, "bench", n_uploads, n_points, concurrency, rng,
                                  label, problems, pid))
        if n_fits == 0:
            return rows, problems
        headers = {"content-type": "application/json"}
        await client.post("/skills", json={"name": "fit10", "dim": 3})

        r, lat = await timed(client, "POST", "/skills/bench/fit", json={})
        if r.status_code != 201:
            problems.append(f"fit of all demos failed: {r.status_code} {r.text[:200]}")
        rows.append(Row(f"fit ({n_uploads} x {n_points} pts)", 1, lat, [lat]))

        for j in range(10):
            await client.post("/skills/fit10/demonstrations",
                              content=orjson.dumps({"positions": demo(j, 1000, rng)},
                                                   option=orjson.OPT_SERIALIZE_NUMPY),
                              headers=headers)
        fit_lat = []
        cpu0 = cpu_seconds(pid)
        t0 = time.perf_counter()
        for _ in range(n_fits):
            r, lat = await timed(client, "POST", "/skills/fit10/fit", json={})
            if r.status_code != 201:
                problems.append(f"fit10 failed: {r.status_code} {r.text[:200]}")
                break
            fit_lat.append(lat)
        rows.append(Row("fit (10 x 1000 pts)", len(fit_lat), time.perf_counter() - t0, fit_lat,
                        "p99 < 100 ms", server_cpu=cpu_seconds(pid) - cpu0))
        rows[-1].ok = rows[-1].pct(99) < 100

        model = (await client.get("/skills/bench/models/latest")).json()
        directrix = np.asarray(model["directrix"])
        radii = np.asarray(model["radii"])
        starts = []
        for _ in range(n_repro):
            k = int(rng.integers(0, len(directrix) // 2))
            starts.append((directrix[k] + rng.normal(0, 0.3 * radii[k] / np.sqrt(3), 3)).tolist())

        async def reproduce(i: int) -> tuple[httpx.Response, float]:
            return await timed(client, "POST", "/skills/bench/reproductions",
                               json={"start": starts[i]})

        cpu0 = cpu_seconds(pid)
        results, seconds = await run_many(n_repro, repro_concurrency, reproduce)
        repro_cpu = cpu_seconds(pid) - cpu0
        bad = [r for r, _ in results if r.status_code != 200]  # type: ignore[misc]
        if bad:
            problems.append(f"{len(bad)} reproductions failed: {bad[0].text[:200]}")
        rows.append(Row(f"reproduce (x{repro_concurrency} in flight)", n_repro, seconds,
                        [lat for _, lat in results], "p99 < 20 ms",  # type: ignore[misc]
                        server_cpu=repro_cpu))
        rows[-1].ok = rows[-1].pct(99) < 20
    return rows, problems


def canal_serve() -> list[str]:
    """The command a user types: the ``canal`` script installed beside this Python."""
    script = Path(sys.executable).with_name("canal")
    if script.exists():
        return [str(script), "serve"]
    return [sys.executable, "-c", "from canal_client.cli import app; app()", "serve"]


def serve_and_bench(extra: list[str], label: str, args: argparse.Namespace, n_uploads: int,
                    n_fits: int, n_repro: int) -> tuple[list[Row], list[str]]:
    """Start ``canal serve`` with its defaults plus ``extra`` and run :func:`bench` on it."""
    port = free_port()
    with tempfile.TemporaryDirectory(prefix="canal-bench-") as data:
        env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(ROOT / "service"),
                                                            str(ROOT / "clients"),
                                                            os.environ.get("PYTHONPATH", "")])}
        # Only the port, the data folder and the bridge's port (7447 may be taken on a shared
        # machine) differ from what a user starts; logs stay at info, like in a terminal.
        command = [*canal_serve(), "--port", str(port), "--data-dir", data,
                   "--zenoh-listen", f"tcp/127.0.0.1:{free_port()}", *extra]
        with open(Path(data) / "serve.log", "wb") as log:
            server = subprocess.Popen(command, env=env, stdout=log, stderr=log)
            url = f"http://127.0.0.1:{port}"
            try:
                deadline = time.monotonic() + 180  # imports take long on a busy machine
                while True:
                    try:
                        if httpx.get(f"{url}/healthz", timeout=1).status_code == 200:
                            break  # 503 "starting" while the app loads
                    except httpx.TransportError:
                        pass
                    if server.poll() is not None or time.monotonic() > deadline:
                        return [], [f"{label}: service did not start"]
                    time.sleep(0.1)
                return asyncio.run(bench(url, label, n_uploads, 1000, n_fits, n_repro,
                                         args.concurrency, args.repro_concurrency, server.pid))
            finally:
                # A graceful stop: the recorder first writes what the burst left queued
                # (a few seconds for 1,000 demos on a busy machine).
                server.terminate()
                try:
                    server.wait(180)
                except subprocess.TimeoutExpired:
                    server.kill()
                    server.wait(15)


def upload_stages(n: int, n_points: int = 1000) -> list[tuple[str, float]]:
    """CPU ms per upload of each stage of the JSON upload path, run here in one thread.

    The same calls the service makes, in its order, on ``n`` demos of ``n_points`` points,
    against a real SQLite file and a real recorder reading from it (as ``canal serve``
    runs them). Process time: the writer's row includes Rerun's own threads.
    """
    sys.path[:0] = [str(ROOT / "service")]
    from canal_service.recording import Recorder
    from canal_service.recording.source import DbSource
    from canal_service.storage import Database
    from canal_service.storage import repository as repo
    from canal_service.validation import check_fittable, check_positions

    from canal_protocol.schemas import demonstration_from_json

    rng = np.random.default_rng(1)
    bodies = [orjson.dumps({"positions": demo(j, n_points, rng), "label": f"d{j}"},
                           option=orjson.OPT_SERIALIZE_NUMPY) for j in range(n)]
    cpu = time.process_time
    out: list[tuple[str, float]] = []

    def stage(name: str, t0: float) -> None:
        out.append((name, (cpu() - t0) / n * 1000))

    with tempfile.TemporaryDirectory(prefix="canal-bench-stages-") as data:
        db = Database(f"sqlite:///{data}/canal.db")
        db.migrate()
        with db.write() as session:
            repo.create_skill(session, "stages", "", 3)
        # Warm-up outside the timings: first calls import and build what they use.
        check_fittable(check_positions(demonstration_from_json(bodies[0]).positions, 3), None)
        t0 = cpu()
        parsed = [demonstration_from_json(b) for b in bodies]
        stage("parse (JSON to arrays)", t0)
        t0 = cpu()
        checked = [check_positions(p.positions, 3) for p in parsed]
        stage("validate (shape, finite)", t0)
        t0 = cpu()
        for positions in checked:
            check_fittable(positions, None)
        stage("prepare (canal_core, once)", t0)
        t0 = cpu()
        ids = [repo.insert_demonstration(db, "stages", positions, None, None, p.label, "json").id
               for positions, p in zip(checked, parsed, strict=True)]
        stage("DB insert + commit (1 statement)", t0)
        recorder = Recorder(Path(data) / "recordings", source=DbSource(db))
        try:
            recorder.reconcile()  # the start-up pass, not part of any upload
            t0 = cpu()
            for demo_id in ids:
                recorder.demo_added("stages", 3, demo_id, None, None, None)
            stage("recorder enqueue (request path)", t0)
            t0 = cpu()
            recorder.export_rrd("stages").unlink()  # writes everything queued, then exports
            stage("recorder write (writer thread)", t0)
        finally:
            recorder.close()
            db.dispose()
    return out


def print_stages(stages: list[tuple[str, float]], rows: list[Row]) -> None:
    print("\nupload path by stage, CPU ms per 1,000-point JSON upload (process time, this process)")
    for name, ms in stages:
        print(f"  {name:<34} {ms:>7.2f}")
    inside = sum(ms for name, ms in stages if not name.startswith("recorder write"))
    print(f"  {'sum before the writer':<34} {inside:>7.2f}")
    for r in rows:
        if r.name.startswith("upload") and r.cpu_ms == r.cpu_ms:
            rec = r.rec_ms if r.rec_ms == r.rec_ms else 0.0
            print(f"  {r.name:<34} {r.cpu_ms:>7.2f} server CPU per upload over HTTP, of which "
                  f"{rec:.2f} recorder writer, ~{r.cpu_ms - inside - rec:.2f} HTTP/framework")


def print_threads(rows: list[Row]) -> None:
    """Server CPU ms per upload by kind of thread, for each burst that has the figures."""
    kinds = ("event loop", "upload lane", "recorder writer", "other threads")
    measured = [r for r in rows if r.threads and r.name.startswith("upload") and r.count]
    if not measured:
        return
    print("\nserver CPU ms per upload by thread during each burst (/proc/PID/task: user + system)")
    print(f"  {'burst':<30}" + "".join(f" {k:>15}" for k in kinds) + f" {'all':>8}")
    for r in measured:
        assert r.threads is not None
        cells = "".join(f" {r.threads.get(k, 0.0) / r.count * 1000:>15.2f}" for k in kinds)
        print(f"  {r.name:<30}{cells} {sum(r.threads.values()) / r.count * 1000:>8.2f}")


def recordings_cost(rows: list[Row], concurrency: int) -> float | None:
    """What recordings cost: 1 - (defaults' upload rate) / (``--no-recordings`` rate) at
    ``concurrency`` clients, both from this run (None when either burst is missing)."""
    by_name = {r.name: r for r in rows}
    on = by_name.get(f"upload defaults x{concurrency}")
    off = by_name.get(f"upload --no-recordings x{concurrency}")
    if on is None or off is None or not off.rate:
        return None
    return 1.0 - on.rate / off.rate


def print_table(rows: list[Row]) -> None:
    print(f"\n{os.cpu_count()} CPUs shared by client and server")
    print("(srv cpu ms: server process CPU per request, the load-independent figure)")
    head = (f"{'step':<30} {'n':>6} {'total s':>8} {'per s':>9} {'p50 ms':>8} {'p99 ms':>8} "
            f"{'srv cpu ms':>10} {'rec cpu ms':>10}  target")
    print(head)
    print("-" * len(head) + "-" * 12)
    for r in rows:
        verdict = "" if r.ok is None else ("  PASS" if r.ok else "  FAIL")
        cpu = f"{r.cpu_ms:>10.2f}" if r.cpu_ms == r.cpu_ms else f"{'':>10}"
        rec = f"{r.rec_ms:>10.2f}" if r.rec_ms == r.rec_ms else f"{'':>10}"
        print(f"{r.name:<30} {r.count:>6} {r.seconds:>8.2f} {r.rate:>9.1f} {r.pct(50):>8.1f} "
              f"{r.pct(99):>8.1f} {cpu} {rec}  {r.target}{verdict}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="a tenth of the work (smoke run)")
    p.add_argument("--concurrency", type=int, default=8,
                   help="requests in flight for uploads (default 8)")
    p.add_argument("--repro-concurrency", type=int, default=2,
                   help="requests in flight for reproductions (default 2: a latency target, "
                        "measured with client and server sharing the machine's 2 cores)")
    args = p.parse_args(argv)
    n_uploads, n_fits, n_repro = (100, 10, 100) if args.quick else (1000, 30, 1000)

    rows, problems = serve_and_bench([], "defaults", args, n_uploads, n_fits, n_repro)
    rows_off, problems_off = serve_and_bench(["--no-recordings"], "--no-recordings", args,
                                             n_uploads, 0, 0)
    for row in rows_off:
        row.target, row.ok = "", None  # the target is for the defaults
    rows += rows_off
    problems += problems_off
    stages = upload_stages(50 if args.quick else 300)
    cost = recordings_cost(rows, args.concurrency)
    print_table(rows)
    if cost is not None:
        print(f"recordings cost at x{args.concurrency}: {cost:+.1%} of the --no-recordings rate "
              f"(target <= 10 %){'  PASS' if cost <= 0.10 else '  FAIL'}")
    print_threads(rows)
    print_stages(stages, rows)
    summary = [summary_row(f"service {r.name}", r.rate, "1/s", "target", 200, better="higher")
               for r in rows if r.target == ">= 200/s"]
    summary += [summary_row(f"service {r.name}", r.rate, "1/s", better="higher")
                for r in rows if r.name.startswith("upload --no-recordings x")
                and r.name != "upload --no-recordings x1"]
    if cost is not None:
        summary.append(summary_row(f"service recordings cost x{args.concurrency}", 100 * cost,
                                   "%", "target", 10.0))
    summary += [summary_row(f"service {r.name} p99", r.pct(99), "ms", "target",
                            float(r.target.split()[2])) for r in rows if r.target.startswith("p99")]
    write_summary("service", summary)
    for problem in problems:
        print("PROBLEM:", problem)
    failed = problems or any(r.ok is False for r in rows) or (cost is not None and cost > 0.10)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
