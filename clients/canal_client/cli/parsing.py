"""Values typed on the command line: points and quaternions (``0,0.1,0``), and numbers, ids,
versions and texts checked against the HTTP contract's own limits. A bad one is a usage
error (exit code 2) naming the option, what it expects and what came, before any request."""

from __future__ import annotations

import math
import re
import typing
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Annotated, Any, TypeVar

import annotated_types
import numpy as np
import typer
from pydantic import BaseModel, ConfigDict, TypeAdapter, ValidationError
from pydantic.fields import FieldInfo
from typer.core import TyperCommand

from canal_core.validation import FloatArray
from canal_protocol.schemas import Id

T = TypeVar("T")


def field_type(model: type[BaseModel], field: str) -> Any:
    """A pydantic model's field as a type with its limits (``Annotated[float, Gt(0), Le(10)]``)."""
    info = model.model_fields[field]
    return Annotated[info.annotation, *info.metadata]


def _limits(annotation: Any) -> dict[str, Any]:
    """The limits (``ge``, ``gt``, ``le``, ``lt``, ``max_length``) of an ``Annotated`` type."""
    found: dict[str, Any] = {}
    rules = list(typing.get_args(annotation)[1:]) if typing.get_origin(annotation) is Annotated else []
    while rules:
        rule = rules.pop(0)
        if isinstance(rule, FieldInfo):
            rules.extend(rule.metadata)
            continue
        if isinstance(rule, annotated_types.Interval):
            rules.extend(rule)  # Ge, Gt, Le, Lt
            continue
        for name in ("ge", "gt", "le", "lt", "max_length"):
            if getattr(rule, name, None) is not None:
                found.setdefault(name, getattr(rule, name))
    return found


def field_bounds(model: type[BaseModel], field: str) -> tuple[Any, Any]:
    """The (minimum, maximum) a pydantic model's field accepts (``ge``/``le``), None when open."""
    limits = _limits(field_type(model, field))
    return limits.get("ge"), limits.get("le")


def _base(annotation: Any) -> Any:
    """``int`` of ``Annotated[int | None, ...]``."""
    if typing.get_origin(annotation) is Annotated:
        annotation = typing.get_args(annotation)[0]
    args = [a for a in typing.get_args(annotation) if a is not type(None)]
    return args[0] if len(args) == 1 else annotation


def expected_words(annotation: Any) -> str:
    """What a value of the type must be, in words: ``a number in (0, 10]``, ``a whole number
    in [1, 2147483647]``, ``text of at most 200 characters``."""
    limits, base = _limits(annotation), _base(annotation)
    if base is str:
        return f"text of at most {limits['max_length']} characters" if "max_length" in limits else "text"
    kind = "a whole number" if base is int else "a number"
    shown = {k: f"{v:g}" if isinstance(v, float) else str(v) for k, v in limits.items()}
    low = f"[{shown['ge']}" if "ge" in shown else f"({shown['gt']}" if "gt" in shown else None
    high = f"{shown['le']}]" if "le" in shown else f"{shown['lt']})" if "lt" in shown else None
    if low and high:
        return f"{kind} in {low}, {high}"
    if low is not None:
        return f"{kind} {'>=' if low[0] == '[' else '>'} {low[1:]}"
    if high is not None:
        return f"{kind} {'<=' if high[-1] == ']' else '<'} {high[:-1]}"
    return f"a finite {kind.removeprefix('a ')}" if base is float else kind


def _came(text: str) -> str:
    """What was typed, for a usage error: the text, or its length when it is long."""
    return repr(text) if len(text) <= 40 else f"{len(text)} characters"


def contract_parser(annotation: Any, expected: str | None = None) -> Callable[[object], Any]:
    """A parser for an option or argument whose value goes into a request: the value typed,
    checked against the contract's own type and limits (:func:`field_type` of a
    canal_protocol schema, or one of its types such as :data:`~canal_protocol.schemas.Id`),
    or a usage error saying what was expected and what came. Numbers must be finite: the
    service refuses NaN and infinity, which typer's own range check lets through."""
    adapter: TypeAdapter[Any] = TypeAdapter(annotation, config=ConfigDict(allow_inf_nan=False))
    words = expected or expected_words(annotation)

    def parse(text: object) -> Any:
        if not isinstance(text, str):  # a default
            return text
        try:
            value = adapter.validate_python(text)
        except ValidationError:
            raise typer.BadParameter(f"expected {words}, got {_came(text)}") from None
        if isinstance(value, float) and not math.isfinite(value):  # a type without its own rule
            raise typer.BadParameter(f"expected {words}, got {_came(text)}")
        return value

    return parse


_ID_LIMITS = _limits(Id)
#: A model version typed as ``--model``: 'latest' or a version (the contract's ``ModelRef``).
_VERSION = contract_parser(Id, f"'latest' or a model version in [{_ID_LIMITS['ge']}, {_ID_LIMITS['le']}]")


def model_version(text: object) -> str:
    """``--model``: 'latest' or a version number (as text, the way the client takes it)."""
    return "latest" if text == "latest" else str(_VERSION(text))


#: A stored id (demonstration, correction) typed on the command line.
stored_id = contract_parser(Id)


def existing_file(path: Path, hint: str, *, folder: bool = False) -> None:
    """A file the command reads must be there, a regular file (or a folder, with ``folder``,
    where the command takes one): a usage error naming the path, before any request."""
    if not path.exists():
        raise typer.BadParameter(f"no file {str(path)!r}", param_hint=hint)
    if path.is_dir():
        if not folder:
            raise typer.BadParameter(f"expected a file, got the folder {str(path)!r}",
                                     param_hint=hint)
    elif not path.is_file():
        raise typer.BadParameter(f"expected a regular file, got {str(path)!r} (a device, pipe "
                                 "or socket)", param_hint=hint)


_NEGATIVE_NUMBER = re.compile(r"-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")


class NumbersAsArguments(TyperCommand):
    """A command whose arguments are numbers: ``-1`` typed as one is the argument (refused by
    its own check, naming it), not an unknown option "-1". Any other unknown option is still
    "No such option"."""

    def parse_args(self, ctx: Any, args: list[str]) -> list[str]:  # typer's vendored click Context
        names = {n for p in self.get_params(ctx) for n in (*p.opts, *p.secondary_opts)}
        dashed = [a.split("=", 1)[0] for a in args if a.startswith("-") and a != "--"]
        unknown = [a for a in dashed if a not in names]
        if unknown and all(_NEGATIVE_NUMBER.fullmatch(a) for a in unknown):
            ctx.ignore_unknown_options = True
        return super().parse_args(ctx, args)


def choice_parser(choices: Sequence[T], *, any_case: bool = False) -> Callable[[object], T]:
    """A parser for an option of fixed choices (strings or ``StrEnum`` members): the choice
    typed (in any letter case with ``any_case``), or a usage error listing the choices and
    what came. typer's own check of a ``Literal`` or an enum words the refusal as a pydantic
    ``Value error, ...``."""
    by_text = {str(c): c for c in choices}
    listed = ", ".join(map(repr, by_text))

    def parse(text: object) -> T:
        key = str(text).lower() if any_case else str(text)
        if key not in by_text:
            raise typer.BadParameter(f"expected one of {listed}, got {str(text)!r}")
        return by_text[key]

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
