"""``canal correct`` and ``canal corrections list|undo``: a person refines a skill's canal."""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.markup import escape
from rich.table import Table

from canal_core.validation import FloatArray
from canal_protocol.codecs.csv_table import CsvError, csv_table
from canal_protocol.options import CORRECTION_KINDS, MAX_CORRECTION_WEIGHT, CorrectionKind

from .output import out, print_json, time_text
from .parsing import choice_parser
from .session import connected, options

app = typer.Typer(help="List and undo a skill's corrections.", no_args_is_help=True)


def read_path(path: Path, dim: int) -> FloatArray:
    """A correction's samples (M, dim) from .csv/.txt (read as the service reads a
    demonstration upload: :mod:`canal_protocol.codecs.csv_table`), .npy ((M, dim), or
    (M, dim + 1) with time first, as an upload) or .json (rows, or {"samples": rows})."""
    return samples_of(file_bytes(path), path, dim)


def file_bytes(path: Path) -> bytes:
    """A correction file's bytes, or a usage error naming FILE (before any request)."""
    if path.suffix.lower() not in (".csv", ".txt", ".npy", ".json"):
        raise typer.BadParameter(f"expected a .csv, .npy or .json file, got {path.name!r}",
                                 param_hint="FILE")
    try:
        return path.read_bytes()
    except OSError as exc:
        raise typer.BadParameter(f"cannot read {path}: {exc.strerror or exc}",
                                 param_hint="FILE") from exc


def samples_of(data: bytes, path: Path, dim: int) -> FloatArray:
    """The samples (M, dim) of a correction file's bytes (see :func:`read_path`)."""
    suffix = path.suffix.lower()
    try:
        if suffix in (".csv", ".txt"):
            return csv_table(data, dim).positions
        if suffix == ".npy":
            rows = np.load(io.BytesIO(data), allow_pickle=False)
        else:
            body = json.loads(data)
            rows = body["samples"] if isinstance(body, dict) else body
        samples = np.asarray(rows, dtype=np.float64)
    except CsvError as exc:
        raise typer.BadParameter(f"cannot read {path}: {exc.message}", param_hint="FILE") from exc
    except (ValueError, KeyError, TypeError) as exc:
        raise typer.BadParameter(f"cannot read {path}: {exc}", param_hint="FILE") from exc
    if suffix == ".npy" and samples.ndim == 2 and samples.shape[1] == dim + 1:
        samples = samples[:, 1:]  # time first, as in a demonstration upload
    if samples.ndim != 2 or samples.shape[1] != dim:
        raise typer.BadParameter(
            f"expected rows of {'x,y' if dim == 2 else 'x,y,z'} for a {dim}-D skill, got shape "
            f"{samples.shape}", param_hint="FILE")
    return samples


def correct(
    ctx: typer.Context,
    skill: str,
    file: Annotated[Path, typer.Argument(help="The corrected path: .csv (as `canal demo add` reads it), .npy or .json.")],
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
    data = file_bytes(file)
    with connected(ctx) as c:
        # The columns a CSV is read by (x, y or x, y, z) are the skill's.
        samples = samples_of(data, file, c.get_skill(skill).dim)
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
