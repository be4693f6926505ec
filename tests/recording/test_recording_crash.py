"""kill -9 mid-recording: the files left on disk stay readable and lose at most a flush interval."""

from __future__ import annotations

import json
import os
import signal
import struct
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

from canal_service.recording import Recorder
from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader
from recording_helpers import mcap_counts, rrd_rows, rrd_verify

HERE = Path(__file__).parent
FLUSH_S = 0.2


def _crash(root: Path) -> dict[str, int]:
    """Run the child, wait well past a flush interval after its session, SIGKILL it."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(HERE), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.Popen([sys.executable, str(HERE / "crash_child.py"), str(root), str(FLUSH_S)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        line = proc.stdout.readline() if proc.stdout else ""
        assert line.startswith("LOGGED"), (line, proc.stderr.read() if proc.stderr else "")
        time.sleep(5 * FLUSH_S)
        proc.send_signal(signal.SIGKILL)
        assert proc.wait(timeout=30) == -signal.SIGKILL
    finally:
        if proc.poll() is None:
            proc.kill()
    return json.loads(line.split(" ", 1)[1])


def _unfinished_mcap_counts(path: Path) -> Counter[str]:
    """Topic counts read by mcap's non-seeking reader, up to where the crash cut the file."""
    counts: Counter[str] = Counter()
    with open(path, "rb") as f:
        messages = NonSeekingReader(f).iter_messages(log_time_order=False)
        while True:
            try:
                _, channel, _ = next(messages)
            except StopIteration:
                break
            except (McapError, struct.error):  # the record the kill cut short
                break
            counts[channel.topic] += 1
    return counts


def test_sigkill_leaves_readable_files_and_a_restart_recovers_them(
        tmp_path: Path, rerun_env: dict[str, str]) -> None:
    root = tmp_path / "rec"
    logged = _crash(root)
    skill = root / "pour"
    open_mcap, open_rrd = skill / "seg-000001.open.mcap", skill / "seg-000001.open.rrd"
    assert open_mcap.exists() and open_rrd.exists()

    # MCAP: no summary, but every flushed chunk reads back with the non-seeking reader.
    counts = _unfinished_mcap_counts(open_mcap)
    assert counts["/canal/demos"] == logged["demos"] + logged["removed"]
    assert counts["/canal/model"] == logged["versions"]
    assert counts["/canal/reproductions"] == 1
    assert counts["/live/ur5/pose"] >= logged["live"]

    # RRD: no footer, otherwise valid.
    verify = rrd_verify(open_rrd, rerun_env, footers=False)
    assert verify.returncode == 0, verify.stderr[-2000:]
    rows = rrd_rows(open_rrd, rerun_env)
    assert sum(n for (entity, component), n in rows.items()
               if entity.startswith("/model/v") and component == "Mesh3D:vertex_positions"
               ) == logged["versions"]
    assert rows[("/demos/1", "Clear:is_recursive")] == 1
    assert rows[("/live/ur5/pose", "Points3D:positions")] >= logged["live"]

    # A new recorder on the same root finishes the leftovers; exports hold the pre-crash data.
    rec = Recorder(root, flush_interval_s=FLUSH_S)
    try:
        mcap_path, rrd_path = rec.export_mcap("pour"), rec.export_rrd("pour")
    finally:
        rec.close()
    assert not open_mcap.exists() and not open_rrd.exists()
    recovered = mcap_counts(mcap_path)
    assert recovered["/canal/demos"] == counts["/canal/demos"]
    assert recovered["/live/ur5/pose"] >= counts["/live/ur5/pose"]
    assert rrd_verify(rrd_path, rerun_env).returncode == 0
    assert rrd_rows(rrd_path, rerun_env)[("/live/ur5/pose", "Points3D:positions")] >= logged["live"]


