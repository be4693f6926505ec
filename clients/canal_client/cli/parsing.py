"""Points and quaternions typed on the command line (``0,0.1,0``); a bad one is a usage
error (exit code 2) naming the option."""

from __future__ import annotations

import numpy as np
import typer

from canal_core.validation import FloatArray


def _numbers(text: str) -> list[float]:
    try:
        return [float(v) for v in text.replace(" ", "").split(",") if v != ""]
    except ValueError:
        return []


def parse_point(text: str, option: str = "--start") -> FloatArray:
    """``x,y[,z]`` as an array of shape (2,) or (3,)."""
    values = _numbers(text)
    if len(values) not in (2, 3) or not np.all(np.isfinite(values)):
        raise typer.BadParameter(f"expected 2 or 3 comma-separated numbers like 0,0.1,0, "
                                 f"got {text!r}", param_hint=option)
    return np.asarray(values, dtype=np.float64)


def parse_quaternion(text: str, option: str = "--start-orientation") -> FloatArray:
    """``qx,qy,qz,qw`` as an array of shape (4,) (the service checks that it is a unit one)."""
    values = _numbers(text)
    if len(values) != 4 or not np.all(np.isfinite(values)):
        raise typer.BadParameter(f"expected 4 comma-separated numbers qx,qy,qz,qw like 0,0,0,1, "
                                 f"got {text!r}", param_hint=option)
    return np.asarray(values, dtype=np.float64)
