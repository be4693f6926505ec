"""Recordings behind a load balancer: what an export costs after a change on another replica.

Run: ``.venv/bin/python bench/replicas.py`` (``--quick``: 20 demos, 2 rounds).

Two replicas as a user runs them (``canal serve`` with its defaults, each with its own data
folder, ``--no-zenoh`` on the second as docs/deployment.md says) on one throwaway PostgreSQL
cluster (needs ``initdb``/``pg_ctl`` on PATH). Replica B serves every change: 100 uploads of
1,000-point JSON demos and a fit, then per round one more upload, one more fit or 10
reproductions. Replica A serves only exports: each of its exports first logs from the
database what B changed since A's last export.

The yardstick is B's own export of the same state in the same run: B's writer logged the
changes as they came, so its export only closes the open segment and merges. Every export
is checked to hold every demo, model and reproduction (mcap's reader). Timing is wall clock
of ``GET /skills/<name>/recording.mcap`` from a client on the same (shared, 2-core) machine:
read the ratios, not the absolute figures.

What keeping reproductions for the recordings costs a reproduction: B (defaults: each
reproduction is stored) against a third replica C started with
``--recordings-reproductions-kept 0``, on the same skill and database, alternated in rounds
of 50 sequential requests; p50 of each.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import shutil
import socket
import statistics
import subprocess
import sys
import tempfile
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import orjson

if __package__:
    from bench.common import summary_row, write_section, write_summary
else:  # run as a file (python bench/x.py): bench/ is sys.path[0]
    from common import summary_row, write_section, write_summary

NOTE = """Read it as ratios within one run: on a shared machine single exports move by tens of
per cent from run to run. A change made on another replica costs an export about what it
costs the replica that served it, a fit up to about twice that (the exporting replica
builds the model's geometry then, which the serving one did when it fitted). The first export of a skill a replica never served logs all of it,
about a rebuild, several times the serving replica's export; it happens once per replica and
skill. Keeping a reproduction is a database write on the request: on PostgreSQL a round trip
and a commit, which on a loaded machine costs several times the reproduction's computation."""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextlib.contextmanager
def postgres() -> Iterator[str]:
    """A throwaway PostgreSQL cluster on loopback; yields a database URL."""
    folder = Path(tempfile.mkdtemp(prefix="canal-bench-pg-"))
    prefix: list[str] = []
    if os.geteuid() == 0:
        prefix = ["runuser", "-u", "postgres", "--"]
        shutil.chown(folder, "postgres", "postgres")
    port = free_port()
    data = folder / "data"

    def run(*cmd: str) -> None:
        subprocess.run([*prefix, *cmd], check=True, capture_output=True, timeout=120)

    run("initdb", "-D", str(data), "-A", "trust", "-U", "canal", "--no-sync")
    run("pg_ctl", "-D", str(data), "-o", f"-k {folder} -p {port} -h 127.0.0.1 -F",
        "-l", str(folder / "log"), "-w", "start")
    try:
        import psycopg

        name = f"bench_{uuid.uuid4().hex[:8]}"
        with psycopg.connect(f"postgresql://canal@127.0.0.1:{port}/postgres",
                             autocommit=True) as conn:
            conn.execute(f'CREATE DATABASE "{name}"')
        yield f"postgresql+psycopg://canal@127.0.0.1:{port}/{name}"
    finally:
        with contextlib.suppress(Exception):
            run("pg_ctl", "-D", str(data), "-m", "fast", "-w", "stop")
        shutil.rmtree(folder, ignore_errors=True)


def canal_serve() -> list[str]:
    """The command a user types: the ``canal`` script installed beside this Python."""
    script = Path(sys.executable).with_name("canal")
    if script.exists():
        return [str(script), "serve"]
    return [sys.executable, "-c", "from canal_client.cli import app; app()", "serve"]


@contextlib.contextmanager
def replica(url: str, *extra: str) -> Iterator[str]:
    """``canal serve`` with its defaults on ``url``'s database; yields its base URL."""
    port = free_port()
    data = Path(tempfile.mkdtemp(prefix="canal-bench-replica-"))
    command = [*canal_serve(), "--port", str(port), "--data-dir", str(data),
               "--database-url", url, *extra]
    if "--no-zenoh" not in extra:
        command += ["--zenoh-listen", f"tcp/127.0.0.1:{free_port()}"]
    with open(data / "serve.log", "wb") as log:
        server = subprocess.Popen(command, stdout=log, stderr=log,
                                  env={**os.environ, "RERUN_TELEMETRY_ENABLED": "false"})
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 180
        while True:
            try:
                if httpx.get(f"{base}/healthz", timeout=1).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            if server.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"replica did not start: {(data / 'serve.log').read_text()}")
            time.sleep(0.1)
        yield base
    finally:
        server.terminate()
        try:
            server.wait(120)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait(15)
        shutil.rmtree(data, ignore_errors=True)


def demo(k: int, n: int = 1000) -> bytes:
    s = np.linspace(0.0, 1.0, n)
    rng = np.random.default_rng(k)
    pts = np.c_[np.cos(3 * s), np.sin(3 * s), s] + 0.01 * rng.standard_normal((n, 3))
    return orjson.dumps({"positions": pts.tolist()})


def export(http: httpx.Client, skill: str) -> tuple[float, dict[str, int]]:
    """(milliseconds, counts of demos / models / reproductions) of one MCAP export."""
    from mcap.reader import make_reader

    t0 = time.perf_counter()
    r = http.get(f"/skills/{skill}/recording.mcap")
    ms = (time.perf_counter() - t0) * 1e3
    assert r.status_code == 200, r.text
    demos: set[str] = set()
    versions: set[int] = set()
    numbers: set[int] = set()
    for _s, channel, message in make_reader(io.BytesIO(r.content)).iter_messages():
        if channel.topic == "/canal/demos":
            data = orjson.loads(message.data)
            demos |= {e["id"] for e in data["entities"]}
            demos -= {d["id"] for d in data["deletions"]}
        elif channel.topic == "/canal/model_info":
            versions.add(int(orjson.loads(message.data)["version"]))
        elif channel.topic == "/canal/reproduction_result":
            numbers.add(int(orjson.loads(message.data)["number"]))
    return ms, {"demos": len(demos), "models": len(versions), "reproductions": len(numbers)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="20 demos, 2 rounds")
    args = parser.parse_args()
    n_demos, rounds = (20, 2) if args.quick else (100, 3)
    if shutil.which("initdb") is None or shutil.which("pg_ctl") is None:
        print("bench/replicas.py: needs the PostgreSQL server binaries (initdb, pg_ctl); skipped")
        return 0
    rows: list[tuple[str, float, float]] = []
    with postgres() as url, replica(url) as url_a, replica(url, "--no-zenoh") as url_b, \
            httpx.Client(base_url=url_a, timeout=600) as a, \
            httpx.Client(base_url=url_b, timeout=600) as b:
        skill = "bench"
        assert b.post("/skills", json={"name": skill, "dim": 3}).status_code == 201
        headers = {"content-type": "application/json"}
        for k in range(n_demos):
            r = b.post(f"/skills/{skill}/demonstrations", content=demo(k), headers=headers)
            assert r.status_code == 201, r.text
        assert b.post(f"/skills/{skill}/fit", json={}).status_code == 201
        expected = {"demos": n_demos, "models": 1, "reproductions": 0}

        def both(label: str) -> None:
            ms_a, got_a = export(a, skill)
            ms_b, got_b = export(b, skill)
            assert got_a == expected == got_b, (label, got_a, got_b, expected)
            rows.append((label, ms_a, ms_b))

        both(f"first export on A ({n_demos} demos and 1 model written by B)")
        for _ in range(rounds):
            both("no change since the last export")
        extra = n_demos
        for _ in range(rounds):
            r = b.post(f"/skills/{skill}/demonstrations", content=demo(extra), headers=headers)
            assert r.status_code == 201, r.text
            extra += 1
            expected["demos"] += 1
            both("after 1 upload on B")
        for _ in range(rounds):
            assert b.post(f"/skills/{skill}/fit", json={}).status_code == 201
            expected["models"] += 1
            both("after 1 fit on B")
        for _ in range(rounds):
            for k in range(10):
                r = b.post(f"/skills/{skill}/reproductions", json={"start": [1.0, 0.0, 0.01 * k]})
                assert r.status_code == 200, r.text
            expected["reproductions"] += 10
            both("after 10 reproductions on B")
        t0 = time.perf_counter()
        rebuilt = a.post(f"/skills/{skill}/recording/rebuild").json()
        rebuild_ms = (time.perf_counter() - t0) * 1e3
        assert rebuilt["demos"] == expected["demos"], rebuilt
        with replica(url, "--no-zenoh", "--recordings-reproductions-kept", "0") as url_c, \
                httpx.Client(base_url=url_c, timeout=600) as c:
            stored, unstored = reproduction_latencies(b, c, skill, rounds)
        compute_ms, keep_ms = keeping_in_process(url, skill, 50 if args.quick else 200)


    print(__doc__.splitlines()[0])
    print(f"skill of {n_demos} demos x 1000 points on one PostgreSQL, two `canal serve` "
          "replicas; ms per GET recording.mcap, median of the rounds")
    print("| export after                                       | on A (ms) | on B (ms) | A / B |")
    print("|----------------------------------------------------|-----------|-----------|-------|")
    labels = list(dict.fromkeys(r[0] for r in rows))
    medians: dict[str, tuple[float, float]] = {}
    for label in labels:
        ms_a = statistics.median(r[1] for r in rows if r[0] == label)
        ms_b = statistics.median(r[2] for r in rows if r[0] == label)
        medians[label] = (ms_a, ms_b)
        print(f"| {label:<50} | {ms_a:9.1f} | {ms_b:9.1f} | {ms_a / ms_b:5.2f} |")
    lines = [
        f"skill of {n_demos} demos x 1000 points on one PostgreSQL, two `canal serve` "
        "replicas; ms per `GET recording.mcap`, median of the rounds"
        f"{' (--quick)' if args.quick else ''}", "",
        "| export after | on A, which logs B's changes (ms) | on B, which served them (ms) "
        "| A / B |", "|---|---:|---:|---:|"]
    for label, (ms_a, ms_b) in medians.items():
        lines.append(f"| {label} | {ms_a:.0f} | {ms_b:.0f} | {ms_a / ms_b:.2f} |")
    repro = (f"Rebuild on A from the database (every demo, model and kept reproduction): "
             f"{rebuild_ms:.0f} ms. A reproduction (p50 of {len(stored)} sequential, over "
             f"HTTP) on B, which stores it for the recordings: {statistics.median(stored):.1f} "
             f"ms; on C (`--recordings-reproductions-kept 0`): "
             f"{statistics.median(unstored):.1f} ms "
             f"({statistics.median(stored) / statistics.median(unstored):.2f}x).")
    in_process = (f"In one process on the same database (median of the calls the service "
                  f"makes): computing a reproduction {compute_ms:.2f} ms, keeping it "
                  f"(`insert_reproductions`: one INSERT ... SELECT in a transaction of its "
                  f"own on a pooled connection) {keep_ms:.2f} ms "
                  f"({keep_ms / compute_ms:.2f}x the computation).")
    lines += ["", repro, "", in_process]
    print("\n" + repro + "\n" + in_process)
    first = medians[labels[0]]
    upload = medians["after 1 upload on B"]
    summary: list[dict[str, Any]] = [
        summary_row("export on A after 1 upload on B (100 demos)", upload[0], "ms",
                    peer_name="export on B, same state", peer_value=upload[1]),
        summary_row("first export on A of 100 demos written by B", first[0], "ms",
                    peer_name="rebuild from the database", peer_value=rebuild_ms),
        summary_row("reproduction over HTTP, kept for the recordings (p50)",
                    statistics.median(stored), "ms", peer_name="not kept (C), same skill",
                    peer_value=statistics.median(unstored)),
    ]
    write_summary("replicas", summary)
    write_section("\n".join([*lines, "", NOTE]))
    return 0


def keeping_in_process(url: str, skill: str, n: int) -> tuple[float, float]:
    """Median milliseconds of computing a reproduction and of keeping it, as the service
    calls both (``canal_core`` and ``repository.insert_reproductions``), alternated."""
    from canal_service.storage import Database
    from canal_service.storage import repository as repo

    import canal_core

    db = Database(url)
    try:
        ref = repo.model_ref_by_name(db, skill, None)
        with db.read() as s:
            canal = canal_core.Canal.from_dict(repo.get_model(s, ref.model_id).canal)
        compute, keep = [], []
        for k in range(n):
            t0 = time.perf_counter()
            result = canal.reproduce_detailed(np.array([1.0, 0.0, 0.0005 * (k % 50)]))
            t1 = time.perf_counter()
            repo.insert_reproductions(db, ref.skill_id, ref.skill_created_at, ref.version,
                                      [result], 1000)
            t2 = time.perf_counter()
            compute.append((t1 - t0) * 1e3)
            keep.append((t2 - t1) * 1e3)
        return statistics.median(compute), statistics.median(keep)
    finally:
        db.dispose()


def reproduction_latencies(stores: httpx.Client, plain: httpx.Client, skill: str,
                           rounds: int) -> tuple[list[float], list[float]]:
    """Milliseconds per reproduction on each replica, alternating rounds of 50."""
    out: tuple[list[float], list[float]] = ([], [])
    for k in range(2 * rounds):
        client, times = (stores, out[0]) if k % 2 == 0 else (plain, out[1])
        for j in range(50):
            t0 = time.perf_counter()
            r = client.post(f"/skills/{skill}/reproductions",
                            json={"start": [1.0, 0.0, 0.0005 * j]})
            times.append((time.perf_counter() - t0) * 1e3)
            assert r.status_code == 200, r.text
    return out


if __name__ == "__main__":
    raise SystemExit(main())
