"""Points and quaternions typed on the command line (``0,0.1,0``); a bad one is a usage
error (exit code 2) naming the option."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TypeVar

import numpy as np
import typer

from canal_core.validation import FloatArray

T = TypeVar("T")


def choice_parser(choices: Sequence[T]) -> Callable[[object], T]:
    """A parser for an option of fixed choices (strings or ``StrEnum`` members): the choice
    typed, or a usage error listing the choices and what came. typer's own check of a
    ``Literal`` or an enum words the refusal as a pydantic ``Value error, ...``."""
    by_text = {str(c): c for c in choices}
    listed = ", ".join(map(repr, by_text))

    def parse(text: object) -> T:
        if str(text) not in by_text:
            raise typer.BadParameter(f"expected one of {listed}, got {str(text)!r}")
        return by_text[str(text)]

    return parse


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


#: ``--obstacle KIND:numbers``: how many numbers each kind takes (D = 3, or 2 for a disc and
#: a 2-D box), an optional last one being the clearance.
_OBSTACLE_FORMS = {
    "sphere": "sphere:x,y,z,r[,clearance]",
    "disc": "disc:x,y,r[,clearance]",
    "box": "box:cx,cy,cz,hx,hy,hz[,clearance] (2-D: box:cx,cy,hx,hy[,clearance])",
    "capsule": "capsule:ax,ay,az,bx,by,bz,r[,clearance]",
}


def parse_obstacle(text: str, option: str = "--obstacle") -> dict[str, object]:
    """``sphere:x,y,z,r`` (and the other forms of :data:`_OBSTACLE_FORMS`) as the service's
    obstacle dict (the service checks it against the skill's dimension)."""
    kind, _, rest = text.partition(":")
    kind = kind.strip().lower()
    values = _numbers(rest)
    forms = "; ".join(_OBSTACLE_FORMS.values())
    if kind not in _OBSTACLE_FORMS or not values or not np.all(np.isfinite(values)):
        raise typer.BadParameter(f"expected {forms}; got {text!r}", param_hint=option)
    n = len(values)
    out: dict[str, object]
    if kind == "sphere" and n in (4, 5):
        out = {"kind": kind, "center": values[:3], "radius": values[3]}
    elif kind == "disc" and n in (3, 4):
        out = {"kind": kind, "center": values[:2], "radius": values[2]}
    elif kind == "box" and n in (4, 5, 6, 7):
        d = 3 if n >= 6 else 2
        out = {"kind": kind, "center": values[:d], "half_extents": values[d : 2 * d]}
    elif kind == "capsule" and n in (7, 8):
        out = {"kind": kind, "a": values[:3], "b": values[3:6], "radius": values[6]}
    else:
        raise typer.BadParameter(f"expected {_OBSTACLE_FORMS[kind]}; got {text!r}", param_hint=option)
    used = {"sphere": 4, "disc": 3, "capsule": 7}.get(kind, 6 if n >= 6 else 4)
    if n > used:
        out["clearance"] = values[used]
    return out
