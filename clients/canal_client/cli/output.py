"""What every command prints: the two consoles, one-line errors, JSON, exit codes."""

from __future__ import annotations

import dataclasses
import json
import sys
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel
from rich.console import Console
from rich.markup import escape

EXIT_REFUSED = 1
EXIT_USAGE = 2
EXIT_UNREACHABLE = 3

out = Console(highlight=False, soft_wrap=True)
err = Console(stderr=True, highlight=False, soft_wrap=True)


def error(message: str) -> None:
    """``error: MESSAGE`` on stderr (the message is printed as text, never as markup)."""
    err.print(f"[red]error:[/red] {escape(message)}")


def plain(value: Any) -> Any:
    """JSON-ready form of the client's models and dataclasses, numpy arrays and datetimes."""
    if isinstance(value, BaseModel):
        return plain(value.model_dump())
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, datetime):
        return value.isoformat()
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [plain(v) for v in value]
    return value


def print_json(value: Any) -> None:
    """``value`` as indented JSON on stdout (the ``--json`` output of every command)."""
    sys.stdout.write(json.dumps(plain(value), indent=2) + "\n")
    sys.stdout.flush()


def time_text(value: datetime | None) -> str:
    """A creation time in the tables (seconds, no zone)."""
    return value.strftime("%Y-%m-%d %H:%M:%S") if value else ""
