"""Child process for the disk-full test: files may not grow past a limit (EFBIG, like ENOSPC).

Usage: ``python disk_full_child.py ROOT``. Records fits that do not fit and prints the
recorder's health as JSON, plus how many record calls raised (the contract says none).
"""

from __future__ import annotations

import json
import resource
import signal
import sys
import time
from pathlib import Path

from canal_service.recording import Recorder
from recording_helpers import helix_demo

import canal_core

# Below one model's mesh: every segment fails on its first fit, as on a full disk.
LIMIT = 100_000


def main() -> None:
    demos = [helix_demo(k) for k in range(3)]
    canal = canal_core.fit(demos, n_samples=200)
    rec = Recorder(Path(sys.argv[1]), flush_interval_s=0.1)
    # Writes past the limit now fail with EFBIG instead of killing the process.
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (LIMIT, LIMIT))
    raised = 0
    for version in range(1, 13):
        try:
            rec.model_fitted("pour", version, canal)
        except Exception:
            raised += 1
    time.sleep(1.0)
    health = rec.health()
    rec.close()
    print(json.dumps({"raised": raised, "health": health, "after_close": rec.health()}))


if __name__ == "__main__":
    main()
