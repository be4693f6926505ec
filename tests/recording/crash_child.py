"""Child process for the crash test: records a known session, says so, then streams until killed.

Usage: ``python crash_child.py ROOT FLUSH_INTERVAL_S``. Prints ``LOGGED <json>`` once the known
session is queued; everything after that is live samples at about 2 kHz, never closed.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from canal_service.recording import Recorder
from recording_helpers import helix_demo, record_session

import canal_core


def main() -> None:
    root, interval = Path(sys.argv[1]), float(sys.argv[2])
    demos = [helix_demo(k) for k in range(3)]
    canal = canal_core.fit(demos, n_samples=80)
    # quiet_s=0: write at once; this test is about what the files keep at a kill, not about
    # the writer yielding to a busy request path.
    rec = Recorder(root, flush_interval_s=interval, live_max_hz=None, quiet_s=0)
    logged = record_session(rec, "pour", demos, canal, n_live=200)
    print("LOGGED", json.dumps(logged), flush=True)
    tracker = canal.tracker()
    k = 0
    while True:  # until SIGKILL: there is always an open chunk at the kill
        position = demos[2][k % len(demos[2])]
        rec.live("pour", "ur5", position, tracker.step(position))
        k += 1
        time.sleep(0.0005)


if __name__ == "__main__":
    main()
