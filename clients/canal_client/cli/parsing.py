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
    """Comma-separated numbers; none (``[]``) when one of them is not a number or is left
    empty (``0,,1``, ``,0,1``, ``0,1,``: never read as fewer numbers)."""
    try:
        return [float(v) for v in text.replace(" ", "").split(",")]
    except ValueError:
        return []


def _got(text: str) -> str:
    """What came, for a usage error: the text, and that a number is left empty if one is."""
    empty = "" in text.replace(" ", "").split(",")
    return f"{text!r}" + (" (a number left empty)" if empty else "")


def parse_point(text: str, option: str = "--start") -> FloatArray:
    """``x,y[,z]`` as an array of shape (2,) or (3,)."""
    values = _numbers(text)
    if len(values) not in (2, 3) or not np.all(np.isfinite(values)):
        raise typer.BadParameter(f"expected 2 or 3 comma-separated numbers like 0,0.1,0, "
                                 f"got {_got(text)}", param_hint=option)
    return np.asarray(values, dtype=np.float64)


def parse_quaternion(text: str, option: str = "--start-orientation") -> FloatArray:
    """``qx,qy,qz,qw`` as an array of shape (4,) (the service checks that it is a unit one)."""
    values = _numbers(text)
    if len(values) != 4 or not np.all(np.isfinite(values)):
        raise typer.BadParameter(f"expected 4 comma-separated numbers qx,qy,qz,qw like 0,0,0,1, "
                                 f"got {_got(text)}", param_hint=option)
    return np.asarray(values, dtype=np.float64)


#: ``--obstacle KIND:numbers``: how many numbers each kind takes (D = 3, or 2 for a disc and
#: a 2-D box), an optional last one being the clearance.
_OBSTACLE_FORMS = {
    "sphere": "sphere:x,y,z,r[,clearance]",
    "disc": "disc:x,y,r[,clearance]",
    "box": "box:cx,cy,cz,hx,hy,hz[,clearance] (2-D: box:cx,cy,hx,hy[,clearance])",
    "capsule": "capsule:ax,ay,az,bx,by,bz,r[,clearance]",
}


#: A box of a skill of each dimension (its numbers are read by the skill's dimension when the
#: command knows it: five numbers are a 2-D box and its clearance, or a 3-D box short of hz).
_BOX_FORMS = {2: "box:cx,cy,hx,hy[,clearance]", 3: "box:cx,cy,cz,hx,hy,hz[,clearance]"}


def parse_obstacle(text: str, option: str = "--obstacle", dim: int | None = None) -> dict[str, object]:
    """``sphere:x,y,z,r`` (and the other forms of :data:`_OBSTACLE_FORMS`) as the service's
    obstacle dict (the service checks it against the skill's dimension).

    ``dim``, the skill's dimension when the command knows it, reads a box's numbers: 2 x dim,
    then its clearance (without it, 4 or 5 numbers are a 2-D box, 6 or 7 a 3-D one)."""
    kind, _, rest = text.partition(":")
    kind = kind.strip().lower()
    values = _numbers(rest)
    forms = "; ".join(_OBSTACLE_FORMS.values())
    if kind not in _OBSTACLE_FORMS or not values or not np.all(np.isfinite(values)):
        raise typer.BadParameter(f"expected {forms}; got {_got(text)}", param_hint=option)
    n = len(values)
    out: dict[str, object]
    if kind == "box" and dim in _BOX_FORMS and n in (4, 5, 6, 7) and n not in (2 * dim, 2 * dim + 1):
        raise typer.BadParameter(f"expected {_BOX_FORMS[dim]} for a {dim}-D skill, got {n} "
                                 f"numbers in {text!r}", param_hint=option)
    box_dim = dim if kind == "box" and dim in _BOX_FORMS else (3 if n >= 6 else 2)
    if kind == "sphere" and n in (4, 5):
        out = {"kind": kind, "center": values[:3], "radius": values[3]}
    elif kind == "disc" and n in (3, 4):
        out = {"kind": kind, "center": values[:2], "radius": values[2]}
    elif kind == "box" and n in (4, 5, 6, 7):
        out = {"kind": kind, "center": values[:box_dim], "half_extents": values[box_dim : 2 * box_dim]}
    elif kind == "capsule" and n in (7, 8):
        out = {"kind": kind, "a": values[:3], "b": values[3:6], "radius": values[6]}
    else:
        raise typer.BadParameter(f"expected {_OBSTACLE_FORMS[kind]}; got {text!r}", param_hint=option)
    used = {"sphere": 4, "disc": 3, "capsule": 7}.get(kind, 2 * box_dim)
    if n > used:
        out["clearance"] = values[used]
    return out


def has_box(texts: Sequence[str] | None) -> bool:
    """Whether any ``--obstacle`` is a box: its numbers depend on the skill's dimension."""
    return any(t.partition(":")[0].strip().lower() == "box" for t in texts or [])
