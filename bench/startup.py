"""`python bench/startup.py`: seconds from `python -m canal_service` to the first /healthz 200.

Starts the service as a newcomer does (its own process, fresh data folder, Zenoh bridge and
recordings on, free loopback ports), polls /healthz every 10 ms and stops it; repeats and
reports the median and the spread, beside the cost of a bare `python -c pass` and of a
bare `import fastapi, uvicorn` measured in the same run (the floor any FastAPI service pays).
Target: /healthz answers within 2 s of the start.
"""

from __future__ import annotations

import argparse
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx

if __package__:
    from bench.common import summary_row, write_summary
else:  # run as a file (python bench/x.py): bench/ is sys.path[0]
    from common import summary_row, write_summary


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def time_to_healthz(data: Path) -> tuple[float, float]:
    """(seconds to the first /healthz answer of any status, seconds to the first 200)."""
    rest, zenoh = free_port(), free_port()
    env = dict(os.environ, RERUN_TELEMETRY_ENABLED="false")
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        [sys.executable, "-m", "canal_service", "--port", str(rest), "--data-dir", str(data),
         "--zenoh-listen", f"tcp/127.0.0.1:{zenoh}"],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    first = None
    try:
        with httpx.Client(timeout=10.0) as client:
            while True:
                try:
                    status = client.get(f"http://127.0.0.1:{rest}/healthz").status_code
                    first = first or time.perf_counter() - t0
                    if status == 200:
                        return first, time.perf_counter() - t0
                except httpx.TransportError:
                    pass
                if proc.poll() is not None:
                    raise RuntimeError("the service exited before answering")
                if time.perf_counter() - t0 > 120:
                    raise TimeoutError("no /healthz answer within 120 s")
                time.sleep(0.01)
    finally:
        proc.terminate()
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def time_command(code: str) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", code], check=True)
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="2 runs instead of 7")
    parser.add_argument("--runs", type=int, default=None)
    args = parser.parse_args(argv)
    runs = args.runs or (2 if args.quick else 7)
    answers, starts, bare, floor = [], [], [], []
    with tempfile.TemporaryDirectory(prefix="canal-startup-") as tmp:
        for i in range(runs):
            first, ok = time_to_healthz(Path(tmp) / f"data{i}")
            answers.append(first)
            starts.append(ok)
            bare.append(time_command("pass"))
            floor.append(time_command("import fastapi, uvicorn"))
    med, med_first = statistics.median(starts), statistics.median(answers)
    print(f"service start to first /healthz 200, {runs} runs (fresh data folder, bridge and "
          f"recordings on)")
    print("| measure | median s | min s | max s |")
    print("|---|---:|---:|---:|")
    for name, xs in (("python -m canal_service -> first /healthz answer", answers),
                     ("python -m canal_service -> /healthz 200 (ready)", starts),
                     ("python -c pass", bare), ("python -c 'import fastapi, uvicorn'", floor)):
        print(f"| {name} | {statistics.median(xs):.2f} | {min(xs):.2f} | {max(xs):.2f} |")
    print(f"\ntarget: /healthz answers within 2 s: {'met' if med_first <= 2.0 else 'MISSED'} "
          f"(median {med_first:.2f} s = {med_first / statistics.median(floor):.1f}x importing "
          f"fastapi + uvicorn alone; ready, 200, after {med:.2f} s)")
    write_summary("startup", [
        summary_row("service start to first /healthz answer (median)", med_first, "s",
                    peer_name="target", peer_value=2.0),
        summary_row("service start to /healthz 200, ready (median)", med, "s",
                    peer_name="import fastapi + uvicorn alone", peer_value=statistics.median(floor)),
    ])
    return 0


if __name__ == "__main__":
    sys.exit(main())
