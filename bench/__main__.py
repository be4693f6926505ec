"""`python -m bench`: every benchmark that exists, one after the other (`--quick` passes through)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).parent
SCRIPTS = ["core.py", "service.py", "recording.py", "live.py", "quality.py"]

if __name__ == "__main__":
    for name in SCRIPTS:
        script = HERE / name
        if script.exists():
            print(f"\n== bench/{name} ==", flush=True)
            subprocess.run([sys.executable, str(script), *sys.argv[1:]], check=True)
