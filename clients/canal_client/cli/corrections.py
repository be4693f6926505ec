"""``canal correct`` and ``canal corrections list|undo``: a person refines a skill's canal."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape
from rich.table import Table

from canal_protocol.options import CORRECTION_KINDS, TIME_UNITS, CorrectionKind
from canal_protocol.schemas import CorrectionIn

from ..errors import ArgumentError
from ..rest import guess_format
from .output import out, print_json, time_text
from .parsing import (
    NumbersAsArguments,
    choice_parser,
    contract_parser,
    existing_file,
    field_type,
    model_version,
    stored_id,
)
from .session import connected, options

app = typer.Typer(help="List and undo a skill's corrections.", no_args_is_help=True)


def correct(
    ctx: typer.Context,
    skill: str,
    file: Annotated[Path, typer.Argument(
        help="The corrected path: .csv, .npy or .mcap (read as `canal demo add` reads a "
             "demonstration) or .json (rows, {\"samples\": rows} or a demonstration's "
             "{\"positions\": rows}).")],
    kind: Annotated[CorrectionKind, typer.Option(
        "--kind", "-k", parser=choice_parser(CORRECTION_KINDS),
        help="include: this path is right too; exclude: the robot was pushed away from where "
             "it went (the canal narrows on that side).")] = "include",
    weight: Annotated[float, typer.Option(
        "--weight", "-w", parser=contract_parser(field_type(CorrectionIn, "weight")),
        help="How much an include counts against one demonstration (> 0).")] = 1.0,
    label: Annotated[str, typer.Option(
        "--label", "-l", parser=contract_parser(field_type(CorrectionIn, "label")),
        help="Default: the file's name.")] = "",
    model: Annotated[str, typer.Option("--model", "-m", parser=model_version,
                                       help="Model version corrected, or 'latest'.")] = "latest",
    route: Annotated[int | None, typer.Option(
        "--route", min=0, help="A model of several routes: correct this route's canal "
                               "(default: every route the path passes through).")] = None,
    topic: Annotated[str | None, typer.Option(
        "--topic", help="The pose topic of an .mcap file that has several.")] = None,
    time_unit: Annotated[str | None, typer.Option(
        "--time-unit", parser=choice_parser(tuple(TIME_UNITS)),
        help=f"Unit of the file's time column or timestamps: {', '.join(TIME_UNITS)} (s by "
             "default; ns: a ROS log's nanoseconds). Not for MCAP.")] = None,
) -> None:
    """Refine the skill's canal by a correction: a new model version."""
    try:
        guess_format(file)
    except ArgumentError:
        raise typer.BadParameter(f"expected a .csv, .npy, .mcap or .json file, got {file.name!r}",
                                 param_hint="FILE") from None
    existing_file(file, "FILE")
    with connected(ctx) as c:
        made = c.correct_file(skill, file, kind, model=model, weight=weight,
                              label=label or None, route=route, topic=topic,
                              time_unit=time_unit)
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


@app.command("undo", cls=NumbersAsArguments)
def corrections_undo(ctx: typer.Context, skill: str,
                     id: Annotated[int, typer.Argument(parser=stored_id)]) -> None:
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
