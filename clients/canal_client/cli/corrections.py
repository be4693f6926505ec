"""``canal correct`` and ``canal corrections list|undo``: a person refines a skill's canal."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.markup import escape
from rich.table import Table

from canal_core.validation import FloatArray
from canal_protocol.options import CORRECTION_KINDS, MAX_CORRECTION_WEIGHT, CorrectionKind

from .output import out, print_json, time_text
from .parsing import choice_parser
from .session import connected, options

app = typer.Typer(help="List and undo a skill's corrections.", no_args_is_help=True)


def _numbers_only(line: str) -> bool:
    try:
        [float(cell) for cell in line.split(",")]
    except ValueError:
        return False
    return True


def read_path(path: Path) -> FloatArray:
    """A correction's samples (M, D) from .npy, .json (rows, or {"samples": rows}) or .csv
    (numbers, with or without a header line; with x, y[, z] named, only those columns)."""
    suffix = path.suffix.lower()
    try:
        if suffix == ".npy":
            rows = np.load(path, allow_pickle=False)
        elif suffix == ".json":
            body = json.loads(path.read_text())
            rows = body["samples"] if isinstance(body, dict) else body
        elif suffix in (".csv", ".txt"):
            raw = path.read_bytes()
            # A byte-order mark says the encoding: spreadsheets write UTF-8 with one, Windows
            # tools' "Unicode text" is UTF-16 (as the service reads uploads).
            text = raw.decode("utf-16" if raw.startswith((b"\xff\xfe", b"\xfe\xff")) else "utf-8-sig")
            lines = [line for line in text.splitlines() if line.strip()]
            # Comment lines and a header line come first; numpy.savetxt writes its header as
            # a comment ("# t,x,y,z"), so the last of them names the columns.
            leading = 0
            while leading < len(lines) and not _numbers_only(lines[leading]):
                leading += 1
            header = ([c.strip().lower() for c in lines[leading - 1].lstrip("#").split(",")]
                      if leading else [])
            rows = np.loadtxt(lines[leading:], delimiter=",", ndmin=2)
            if "x" in header and "y" in header:
                # named columns: a `canal reproduce --out` file has t first, qx..qw last
                rows = rows[:, [header.index(a) for a in "xyz" if a in header]]
        else:
            raise typer.BadParameter("expected a .csv, .npy or .json file", param_hint="FILE")
        samples = np.asarray(rows, dtype=np.float64)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise typer.BadParameter(f"cannot read {path}: {exc}", param_hint="FILE") from exc
    if samples.ndim != 2 or samples.shape[1] not in (2, 3):
        raise typer.BadParameter(f"expected rows of x,y[,z], got shape {samples.shape}",
                                 param_hint="FILE")
    return samples[:, :3]


def correct(
    ctx: typer.Context,
    skill: str,
    file: Annotated[Path, typer.Argument(help="The corrected path: .csv (x,y[,z]), .npy or .json.")],
    kind: Annotated[CorrectionKind, typer.Option(
        "--kind", "-k", parser=choice_parser(CORRECTION_KINDS), help="include: this path is right too; exclude: the robot was pushed "
        "away from where it went (the canal narrows on that side).")] = "include",
    weight: Annotated[float, typer.Option(
        "--weight", "-w", help="How much an include counts against one demonstration (> 0).")
    ] = 1.0,
    label: Annotated[str, typer.Option("--label", "-l")] = "",
    model: Annotated[str, typer.Option("--model", "-m",
                                       help="Model version corrected, or 'latest'.")] = "latest",
    route: Annotated[int | None, typer.Option(
        "--route", min=0, help="A model of several routes: correct this route's canal "
                               "(default: every route the path passes through).")] = None,
) -> None:
    """Refine the skill's canal by a correction: a new model version."""
    if model != "latest" and not model.isdigit():
        raise typer.BadParameter("expected a version number or 'latest'", param_hint="--model")
    if not 0 < weight <= MAX_CORRECTION_WEIGHT:
        raise typer.BadParameter(f"expected a weight in (0, {MAX_CORRECTION_WEIGHT:g}], got {weight}",
                                 param_hint="--weight")
    samples = read_path(file)
    with connected(ctx) as c:
        made = c.correct(skill, samples, kind, model=model, weight=weight, label=label,
                         route=route)
    if options(ctx).json:
        print_json(made)
        return
    cor = made.correction
    out.print(f"correction {cor.id} ({cor.kind}) on sections {cor.first_section}-{cor.last_section}: "
              f"model version [bold]{made.version}[/bold] (parent {made.parent_version})"
              + ("" if cor.route is None else f", route {cor.route}"))


@app.command("list")
def corrections_list(ctx: typer.Context, skill: str) -> None:
    """The skill's corrections, oldest first."""
    with connected(ctx) as c:
        rows = c.list_corrections(skill)
    if options(ctx).json:
        print_json(rows)
        return
    table = Table("id", "kind", "label", "points", "sections", "made version", "undone",
                  "created", "route", title="corrections")
    for r in rows:
        table.add_row(str(r.id), r.kind, escape(r.label), str(r.n_points),
                      f"{r.first_section}-{r.last_section}", str(r.model_version),
                      "yes" if r.undone else "", time_text(r.created_at),
                      "" if r.route is None else str(r.route))
    out.print(table)


@app.command("undo")
def corrections_undo(ctx: typer.Context, skill: str, id: int) -> None:
    """A new model version without correction ID (the skill's others re-applied)."""
    with connected(ctx) as c:
        made = c.undo_correction(skill, id)
    if options(ctx).json:
        print_json(made)
        return
    out.print(f"undid correction {id}: model version [bold]{made.version}[/bold] with "
              f"corrections {made.corrections or 'none'}")
    for note in made.notes:
        out.print(f"note: {escape(note)}")
