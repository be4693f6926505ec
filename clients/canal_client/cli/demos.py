"""``canal demo add|list|rm``: demonstrations from files and folders."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime
from pathlib import Path
from typing import Annotated, Any, Protocol

import typer
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn
from rich.table import Table

from canal_protocol.options import TIME_UNITS
from canal_protocol.schemas import DemonstrationIn

from ..errors import ApiError, CanalClientError, ConnectionFailedError, RequestTimeoutError
from ..rest import FILE_FORMATS, guess_format
from .output import EXIT_REFUSED, err, error, out, print_json, time_text
from .parsing import (
    NumbersAsArguments,
    choice_parser,
    contract_parser,
    existing_file,
    field_type,
    stored_id,
)
from .session import connected, options

#: The file kinds ``canal demo add`` takes from a folder.
DEMO_SUFFIXES = (".csv", ".npy", ".json", ".mcap")

app = typer.Typer(help="Add, list and remove demonstrations.", no_args_is_help=True)


class DemoRow(Protocol):
    """What the demonstrations table shows of one demonstration (the client's summary)."""

    @property
    def id(self) -> int: ...
    @property
    def label(self) -> str | None: ...
    @property
    def n_points(self) -> int: ...
    @property
    def source(self) -> str: ...
    @property
    def has_timestamps(self) -> bool: ...
    @property
    def has_orientations(self) -> bool: ...
    @property
    def created_at(self) -> datetime | None: ...


def demo_table(demos: Sequence[DemoRow]) -> Table:
    """The demonstrations table of ``demo list`` and ``skill show``."""
    table = Table("id", "label", "points", "source", "time", "orient.", "created",
                  title="demonstrations")
    for d in demos:
        table.add_row(str(d.id), escape(d.label or ""), str(d.n_points), d.source,
                      "yes" if d.has_timestamps else "", "yes" if d.has_orientations else "",
                      time_text(d.created_at))
    return table


def cli_wording(message: str) -> str:
    """The service's message in this command's words: the REST query parameters
    ``?topic=`` and ``?time_unit=`` are the ``--topic`` and ``--time-unit`` flags here."""
    return message.replace("?topic=", "--topic").replace("?time_unit=", "--time-unit ")


def expand_paths(paths: list[Path]) -> tuple[list[Path], bool]:
    """Files as given; a folder stands for its supported files (not recursive), sorted.
    Also whether a folder held none (reported, and makes the exit code 1)."""
    files: list[Path] = []
    empty = False
    for p in paths:
        if p.is_dir():
            found = sorted(f for f in p.iterdir()
                           if f.is_file() and f.suffix.lower() in DEMO_SUFFIXES)
            if not found:
                error(f"{p}: no .csv, .npy, .json or .mcap files in this folder")
                empty = True
            files.extend(found)
        else:
            files.append(p)
    return files, empty


@app.command("add")
def demo_add(
    ctx: typer.Context,
    skill: str,
    paths: Annotated[list[Path], typer.Argument(
        help="Files (.csv, .npy, .json, .mcap) or folders of them.")],
    topic: Annotated[str | None, typer.Option("--topic", help="MCAP pose topic.")] = None,
    label: Annotated[str | None, typer.Option(
        "--label", parser=contract_parser(field_type(DemonstrationIn, "label")),
        help="Label for every file.")] = None,
    format: Annotated[str | None, typer.Option(
        "--format", parser=choice_parser(FILE_FORMATS, any_case=True),
        help=f"{', '.join(FILE_FORMATS)}: the files' format, whatever their suffix.")] = None,
    time_unit: Annotated[str | None, typer.Option(
        "--time-unit", parser=choice_parser(tuple(TIME_UNITS)),
        help=f"Unit of the files' time column or timestamps: {', '.join(TIME_UNITS)} (s by "
             "default; ns: a ROS log's nanoseconds). Not for MCAP.")] = None,
) -> None:
    """Add one demonstration per file. A folder means every supported file in it
    (.csv, .npy, .json, .mcap; not recursive), in name order. A file that is refused is
    reported as "error: PATH: the service's message" and the others are still added; the
    exit code is then 1. A path that is not there is bad usage (exit code 2), before anything
    is uploaded. Prints each new demonstration's id."""
    for path in paths:
        existing_file(path, "PATHS", folder=True)
    opts = options(ctx)
    files, failed = expand_paths(paths)
    results: list[dict[str, Any]] = []
    with connected(ctx) as c:
        c.get_skill(skill)  # an unknown skill is one error, not one per file
        with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                      console=err, disable=len(files) < 2 or opts.json) as progress:
            task = progress.add_task("uploading", total=len(files))
            for f in files:
                progress.update(task, description=f"uploading {escape(f.name)}")
                try:
                    if not f.is_file():
                        raise CanalClientError("no such file")
                    try:
                        guess_format(f, format)
                    except ValueError:
                        raise CanalClientError(
                            "unsupported file type (expected .csv, .npy, .json or .mcap; "
                            "or pass --format)") from None
                    created = c.upload_demo_file(skill, f, format=format, topic=topic,
                                                 label=label, time_unit=time_unit)
                except CanalClientError as exc:
                    if isinstance(exc, ConnectionFailedError | RequestTimeoutError):
                        raise
                    failed = True
                    problem = ({"type": exc.type, "field": exc.field,
                                "message": cli_wording(exc.message), "status": exc.status}
                               if isinstance(exc, ApiError)
                               else {"type": "client", "field": None, "message": str(exc)})
                    results.append({"file": str(f), "error": problem})
                    progress.console.print(
                        f"[red]error:[/red] {escape(f'{f}: {cli_wording(str(exc))}')}")
                else:
                    results.append({"file": str(f), "id": created.id,
                                    "n_points": created.n_points, "checksum": created.checksum})
                    if not opts.json:
                        out.print(f"{escape(f.name)}: id {created.id} ({created.n_points} points)")
                progress.advance(task)
    if opts.json:
        print_json(results)
    n_ok = sum("id" in r for r in results)
    if not opts.json and len(files) > 1:
        out.print(f"added {n_ok} of {len(files)} demonstrations to {escape(skill)}")
    if failed:
        raise typer.Exit(EXIT_REFUSED)


@app.command("list")
def demo_list(ctx: typer.Context, skill: str) -> None:
    """A skill's demonstrations (no arrays)."""
    with connected(ctx) as c:
        demos = c.list_demos(skill)
    if options(ctx).json:
        print_json(demos)
    elif not demos:
        out.print(f"{escape(skill)} has no demonstrations yet: canal demo add {escape(skill)} FILE")
    else:
        out.print(demo_table(demos))


@app.command("rm", cls=NumbersAsArguments)
def demo_rm(ctx: typer.Context, skill: str,
            ids: Annotated[list[int], typer.Argument(help="Demonstration ids.", parser=stored_id)]
            ) -> None:
    """Remove demonstrations (model versions keep the ids they used). Every id is tried; the
    exit code is 1 when one of them could not be removed."""
    failed = False
    with connected(ctx) as c:
        for demo_id in ids:
            try:
                c.delete_demo(skill, demo_id)
            except ApiError as exc:
                failed = True
                error(f"demonstration {demo_id}: {exc}")
            else:
                if not options(ctx).json:
                    out.print(f"removed demonstration {demo_id}")
    if failed:
        raise typer.Exit(EXIT_REFUSED)
