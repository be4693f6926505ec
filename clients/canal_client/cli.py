"""``canal``: the command line of the Canal service (typer + rich), built on
:class:`canal_client.CanalClient`. ``canal --help`` lists the commands; ``HELP`` below is that
text. Every expected error is one line on stderr and an exit code: 1 refused by the service
(4xx/5xx, or a bad file), 2 usage, 3 service unreachable.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import shlex
import shutil
import subprocess
import sys
from collections.abc import Iterator
from datetime import datetime
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from pydantic import BaseModel
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn
from rich.table import Table

from .errors import ApiError, CanalClientError, ConnectionFailedError, RequestTimeoutError
from .rest import DEFAULT_URL, CanalClient, guess_format

EXIT_REFUSED = 1
EXIT_USAGE = 2
EXIT_UNREACHABLE = 3
DEMO_SUFFIXES = (".csv", ".npy", ".json", ".mcap")

out = Console(highlight=False, soft_wrap=True)
err = Console(stderr=True, highlight=False, soft_wrap=True)

HELP = """Canal: learn robot skills from demonstrations with canal surfaces.

\b
  canal serve [service flags]             run the service here
  canal skill create|list|show|delete     skills
  canal demo add SKILL FILE_OR_FOLDER...  demonstrations (.csv, .npy, .json, .mcap)
  canal demo list|rm SKILL                look at / remove demonstrations
  canal fit SKILL [--cross-section ...]   fit a new model version
  canal reproduce SKILL --start x,y,z     a new trajectory (--out traj.csv)
  canal export SKILL [--rrd F] [--mcap F] download the review recordings
  canal view SKILL [--web]                open the recording in the Rerun viewer
  canal recordings rebuild SKILL          regenerate the recordings from the database
  canal sim SKILL                         drive a simulated robot (Zenoh)

Global options go before the command: canal --url http://host:8000 --token T skill list
(or CANAL_URL / CANAL_TOKEN).

Exit codes: 0 success; 1 the service refused something (its message is printed) or a
simulation that did not end inside the canal; 2 bad usage; 3 the service cannot be reached.
"""

app = typer.Typer(name="canal", help=HELP, no_args_is_help=True, add_completion=False,
                  rich_markup_mode=None, pretty_exceptions_enable=False)
skill_app = typer.Typer(help="Create, list, show and delete skills.", no_args_is_help=True)
demo_app = typer.Typer(help="Add, list and remove demonstrations.", no_args_is_help=True)
app.add_typer(skill_app, name="skill")
app.add_typer(demo_app, name="demo")
recordings_app = typer.Typer(help="The service's review recordings.", no_args_is_help=True)
app.add_typer(recordings_app, name="recordings")


@dataclasses.dataclass
class Options:
    """Global options, shared by every command through the click context."""

    url: str = DEFAULT_URL
    token: str | None = None
    json: bool = False


@app.callback()
def _global(
    ctx: typer.Context,
    url: Annotated[str, typer.Option("--url", envvar="CANAL_URL",
                                     help="Base URL of the Canal service.")] = DEFAULT_URL,
    token: Annotated[str | None, typer.Option("--token", envvar="CANAL_TOKEN",
                                              help="Bearer token, when the service needs one.")
                     ] = None,
    json_output: Annotated[bool, typer.Option("--json",
                                              help="Machine-readable JSON on stdout.")] = False,
) -> None:
    ctx.obj = Options(url=url, token=token or None, json=json_output)


# ---- shared helpers --------------------------------------------------------------------------


def _opts(ctx: typer.Context) -> Options:
    obj = ctx.find_root().obj
    return obj if isinstance(obj, Options) else Options()


def _error(message: str) -> None:
    err.print(f"[red]error:[/red] {escape(message)}")


def _fail_unreachable(exc: CanalClientError, url: str) -> typer.Exit:
    _error(str(exc))
    if isinstance(exc, ConnectionFailedError):
        err.print("hint: start the service with 'canal serve', or point --url (CANAL_URL) "
                  "at a running one")
    return typer.Exit(EXIT_UNREACHABLE)


@contextlib.contextmanager
def _client(ctx: typer.Context) -> Iterator[CanalClient]:
    """A client for the command; every expected error becomes a message and an exit code."""
    opts = _opts(ctx)
    client = CanalClient(opts.url, token=opts.token, timeout=300.0)
    try:
        yield client
    except ApiError as exc:
        _error(str(exc))
        raise typer.Exit(EXIT_REFUSED) from None
    except (ConnectionFailedError, RequestTimeoutError) as exc:
        raise _fail_unreachable(exc, opts.url) from None
    except CanalClientError as exc:
        _error(str(exc))
        raise typer.Exit(EXIT_REFUSED) from None
    finally:
        client.close()


def _plain(value: Any) -> Any:
    """JSON-ready form of the client's models, dataclasses, numpy arrays and datetimes."""
    if isinstance(value, BaseModel):  # the client's models (canal_protocol's)
        return {name: _plain(field) for name, field in value}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, datetime):
        return value.isoformat()
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return value


def _print_json(value: Any) -> None:
    sys.stdout.write(json.dumps(_plain(value), indent=2) + "\n")
    sys.stdout.flush()


def _parse_point(text: str, option: str = "--start") -> np.ndarray:
    try:
        values = [float(v) for v in text.replace(" ", "").split(",") if v != ""]
    except ValueError:
        values = []
    if len(values) not in (2, 3) or not np.all(np.isfinite(values)):
        raise typer.BadParameter(f"expected 2 or 3 comma-separated numbers like 0,0.1,0, "
                                 f"got {text!r}", param_hint=option)
    return np.asarray(values, dtype=np.float64)


def _parse_quaternion(text: str, option: str = "--start-orientation") -> np.ndarray:
    try:
        values = [float(v) for v in text.replace(" ", "").split(",") if v != ""]
    except ValueError:
        values = []
    if len(values) != 4 or not np.all(np.isfinite(values)):
        raise typer.BadParameter(f"expected 4 comma-separated numbers qx,qy,qz,qw like 0,0,0,1, "
                                 f"got {text!r}", param_hint=option)
    return np.asarray(values, dtype=np.float64)


def _time(value: datetime | None) -> str:
    return value.strftime("%Y-%m-%d %H:%M:%S") if value else ""


# ---- serve -----------------------------------------------------------------------------------


@app.command(context_settings={"allow_extra_args": True, "ignore_unknown_options": True,
                               "help_option_names": []})
def serve(ctx: typer.Context) -> None:
    """Run the Canal service here; every argument goes to ``python -m canal_service``
    (try ``canal serve --help``)."""
    from canal_service.__main__ import main

    main(list(ctx.args))


# ---- skills ----------------------------------------------------------------------------------


@skill_app.command("create")
def skill_create(
    ctx: typer.Context,
    name: Annotated[str, typer.Argument(help="Letters, digits, '.', '_', '-'.")],
    dim: Annotated[int, typer.Option("--dim", min=2, max=3, help="2 or 3.")] = 3,
    description: Annotated[str, typer.Option("--description", "-d")] = "",
) -> None:
    """Create a skill (its dimension is fixed for life)."""
    with _client(ctx) as c:
        skill = c.create_skill(name, dim=dim, description=description)
    if _opts(ctx).json:
        _print_json(skill)
    else:
        out.print(f"created skill [bold]{escape(skill.name)}[/bold] ({skill.dim}-D)")


@skill_app.command("list")
def skill_list(ctx: typer.Context) -> None:
    """Every skill with its counts."""
    with _client(ctx) as c:
        skills = c.list_skills()
    if _opts(ctx).json:
        _print_json(skills)
        return
    if not skills:
        out.print("no skills yet: canal skill create NAME")
        return
    table = Table("name", "dim", "demos", "models", "latest", "description")
    for s in skills:
        table.add_row(escape(s.name), str(s.dim), str(s.n_demonstrations), str(s.n_models),
                      "" if s.latest_model_version is None else str(s.latest_model_version),
                      escape(s.description))
    out.print(table)


@skill_app.command("show")
def skill_show(ctx: typer.Context, name: str) -> None:
    """A skill, its demonstrations and its model versions."""
    with _client(ctx) as c:
        skill = c.get_skill(name)
        demos = c.list_demos(name)
        models = c.list_models(name)
    if _opts(ctx).json:
        _print_json({"skill": skill, "demonstrations": demos, "models": models})
        return
    out.print(f"[bold]{escape(skill.name)}[/bold]  {skill.dim}-D  created {_time(skill.created_at)}")
    if skill.description:
        out.print(escape(skill.description))
    latest = skill.latest_model_version
    out.print(f"{skill.n_demonstrations} demonstrations, {skill.n_models} models"
              + (f", latest version {latest}" if latest is not None else ", not fitted yet"))
    if demos:
        out.print(_demo_table(demos))
    if models:
        table = Table("version", "section", "demos", "sections", "fit s", "created",
                      title="models")
        for m in models:
            table.add_row(str(m.version), m.section_kind, str(m.n_demos), str(m.n_sections),
                          f"{m.fit_seconds:.3f}", _time(m.created_at))
        out.print(table)


@skill_app.command("delete")
def skill_delete(
    ctx: typer.Context, name: str,
    yes: Annotated[bool, typer.Option("--yes", "-y", help="Do not ask.")] = False,
) -> None:
    """Delete a skill with all its demonstrations and models."""
    if not yes:
        typer.confirm(f"delete skill {name!r} with all its demonstrations and models?",
                      abort=True, err=True)
    with _client(ctx) as c:
        c.delete_skill(name)
    if not _opts(ctx).json:
        out.print(f"deleted skill {escape(name)}")


# ---- demonstrations --------------------------------------------------------------------------


def _demo_table(demos: list[Any]) -> Table:
    table = Table("id", "label", "points", "source", "time", "orient.", "created",
                  title="demonstrations")
    for d in demos:
        table.add_row(str(d.id), escape(d.label or ""), str(d.n_points), d.source,
                      "yes" if d.has_timestamps else "", "yes" if d.has_orientations else "",
                      _time(d.created_at))
    return table


def cli_wording(message: str) -> str:
    """The service's message in this command's words: the REST query parameter ``?topic=``
    is the ``--topic`` flag here."""
    return message.replace("?topic=", "--topic")


def _expand(paths: list[Path]) -> tuple[list[Path], bool]:
    """Files as given; a folder stands for its supported files (not recursive), sorted.
    Also whether a folder held none (reported, and makes the exit code 1)."""
    files: list[Path] = []
    empty = False
    for p in paths:
        if p.is_dir():
            found = sorted(f for f in p.iterdir()
                           if f.is_file() and f.suffix.lower() in DEMO_SUFFIXES)
            if not found:
                _error(f"{p}: no .csv, .npy, .json or .mcap files in this folder")
                empty = True
            files.extend(found)
        else:
            files.append(p)
    return files, empty


@demo_app.command("add")
def demo_add(
    ctx: typer.Context,
    skill: str,
    paths: Annotated[list[Path], typer.Argument(
        help="Files (.csv, .npy, .json, .mcap) or folders of them.")],
    topic: Annotated[str | None, typer.Option("--topic", help="MCAP pose topic.")] = None,
    label: Annotated[str | None, typer.Option("--label", help="Label for every file.")] = None,
    format: Annotated[str | None, typer.Option(
        "--format", help="csv, npy, json or mcap, for files without a telling suffix.")] = None,
) -> None:
    """Add one demonstration per file. A folder means every supported file in it
    (.csv, .npy, .json, .mcap; not recursive), in name order. A file that is refused is
    reported as "error: PATH: the service's message" and the others are still added; the
    exit code is then 1. Prints each new demonstration's id."""
    opts = _opts(ctx)
    files, failed = _expand(paths)
    results: list[dict[str, Any]] = []
    with _client(ctx) as c:
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
                                                 label=label)
                except CanalClientError as exc:
                    if isinstance(exc, ConnectionFailedError | RequestTimeoutError):
                        raise
                    failed = True
                    error = ({"type": exc.type, "field": exc.field,
                              "message": cli_wording(exc.message), "status": exc.status}
                             if isinstance(exc, ApiError)
                             else {"type": "client", "field": None, "message": str(exc)})
                    results.append({"file": str(f), "error": error})
                    progress.console.print(
                        f"[red]error:[/red] {escape(f'{f}: {cli_wording(str(exc))}')}")
                else:
                    results.append({"file": str(f), "id": created.id,
                                    "n_points": created.n_points, "checksum": created.checksum})
                    if not opts.json:
                        out.print(f"{escape(f.name)}: id {created.id} ({created.n_points} points)")
                progress.advance(task)
    if opts.json:
        _print_json(results)
    n_ok = sum("id" in r for r in results)
    if not opts.json and len(files) > 1:
        out.print(f"added {n_ok} of {len(files)} demonstrations to {escape(skill)}")
    if failed:
        raise typer.Exit(EXIT_REFUSED)


@demo_app.command("list")
def demo_list(ctx: typer.Context, skill: str) -> None:
    """A skill's demonstrations (no arrays)."""
    with _client(ctx) as c:
        demos = c.list_demos(skill)
    if _opts(ctx).json:
        _print_json(demos)
    elif not demos:
        out.print(f"{escape(skill)} has no demonstrations yet: canal demo add {escape(skill)} FILE")
    else:
        out.print(_demo_table(demos))


@demo_app.command("rm")
def demo_rm(ctx: typer.Context, skill: str,
            ids: Annotated[list[int], typer.Argument(help="Demonstration ids.", min=1)]) -> None:
    """Remove demonstrations (model versions keep the ids they used). Every id is tried; the
    exit code is 1 when one of them could not be removed."""
    failed = False
    with _client(ctx) as c:
        for demo_id in ids:
            try:
                c.delete_demo(skill, demo_id)
            except ApiError as exc:
                failed = True
                _error(f"demonstration {demo_id}: {exc}")
            else:
                if not _opts(ctx).json:
                    out.print(f"removed demonstration {demo_id}")
    if failed:
        raise typer.Exit(EXIT_REFUSED)


# ---- fit and reproduce -----------------------------------------------------------------------


class CrossSection(StrEnum):
    circle = "circle"
    mec = "mec"
    ellipse = "ellipse"
    spline = "spline"


class FrameKind(StrEnum):
    rmf = "rmf"
    frenet = "frenet"


class Alignment(StrEnum):
    spline = "spline"
    dtw = "dtw"


class Directrix(StrEnum):
    mean = "mean"
    gmr = "gmr"


class Outside(StrEnum):
    project = "project"
    raise_ = "raise"


@app.command()
def fit(
    ctx: typer.Context,
    skill: str,
    cross_section: Annotated[CrossSection | None, typer.Option("--cross-section", "-c")] = None,
    frames: Annotated[FrameKind | None, typer.Option("--frames")] = None,
    alignment: Annotated[Alignment | None, typer.Option("--alignment")] = None,
    directrix: Annotated[Directrix | None, typer.Option("--directrix")] = None,
    samples: Annotated[int | None, typer.Option("--samples", "-n", min=2, max=5000,
                                                help="Sections along the canal.")] = None,
    frame_smoothing: Annotated[float | None, typer.Option(
        "--frame-smoothing", min=0.0, max=0.25,
        help="Smooth the curve the frames are computed on (fraction of the sections; "
             "0 = the paper's raw frames).")] = None,
    by_time: Annotated[bool, typer.Option(
        "--by-time", help="Align by the demos' time stamps instead of arc length.")] = False,
    demo: Annotated[list[int] | None, typer.Option(
        "--demo", help="Fit only these demonstration ids (repeat).")] = None,
) -> None:
    """Fit a new model version from the skill's demonstrations (service defaults otherwise)."""
    busy = (contextlib.nullcontext() if _opts(ctx).json
            else err.status(f"fitting {escape(skill)}..."))
    with _client(ctx) as c, busy:
        # The enums' values are canal_protocol.options' names; the service checks them.
        names: dict[str, Any] = {
            "cross_section": cross_section and cross_section.value,
            "frames": frames and frames.value, "alignment": alignment and alignment.value,
            "directrix": directrix and directrix.value}
        model = c.fit(skill, **names, n_samples=samples, frame_smoothing=frame_smoothing,
                      by_time=by_time or None, demo_ids=demo or None)
    if _opts(ctx).json:
        _print_json(model)
        return
    out.print(f"fitted {escape(skill)}: version [bold]{model.version}[/bold], "
              f"{model.n_demos} demos, {model.n_sections} {model.section_kind} sections, "
              f"{model.fit_seconds:.3f} s")


def _write_trajectory(path: Path, positions: np.ndarray, payload: Any,
                      orientations: np.ndarray | None = None) -> None:
    suffix = path.suffix.lower()
    path.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".csv":
        header = "x,y,z" if positions.shape[1] == 3 else "x,y"
        table = positions
        if orientations is not None:
            header, table = header + ",qx,qy,qz,qw", np.hstack([positions, orientations])
        np.savetxt(path, table, delimiter=",", header=header, comments="", fmt="%.17g")
    elif suffix == ".npy":
        np.save(path, positions)
    else:
        path.write_text(json.dumps(_plain(payload), indent=2) + "\n")


@app.command()
def reproduce(
    ctx: typer.Context,
    skill: str,
    start: Annotated[str, typer.Option("--start", "-s", help="x,y[,z] start point.")],
    model: Annotated[str, typer.Option("--model", "-m",
                                       help="Model version or 'latest'.")] = "latest",
    out_path: Annotated[Path | None, typer.Option(
        "--out", "-o", help="Save the trajectory: .csv (x,y,z header), .npy (N, D) or .json "
        "(with times and velocities).")
    ] = None,
    outside: Annotated[Outside, typer.Option(
        "--outside", help="A start outside the canal: enter the canal over a short blend, or refuse.")
    ] = Outside.project,
    start_orientation: Annotated[str | None, typer.Option(
        "--start-orientation", "-q",
        help="qx,qy,qz,qw unit quaternion of the start pose (models with orientation carry it; "
             "--out .csv then adds qx,qy,qz,qw columns).")] = None,
    goal: Annotated[str | None, typer.Option(
        "--goal", "-g", help="x,y[,z] goal: the canal is deformed to end there.")] = None,
    duration: Annotated[float | None, typer.Option(
        "--duration", "-d", help="Seconds: stretch the reproduction's times to end there.")
    ] = None,
) -> None:
    """Reproduce a trajectory from a new start (optionally to a new goal, in a given time)."""
    point = _parse_point(start)
    quat = None if start_orientation is None else _parse_quaternion(start_orientation)
    goal_point = None if goal is None else _parse_point(goal, "--goal")
    if duration is not None and not (np.isfinite(duration) and duration > 0):
        raise typer.BadParameter(f"expected seconds > 0, got {duration}", param_hint="--duration")
    if model != "latest" and not model.isdigit():
        raise typer.BadParameter("expected a version number or 'latest'", param_hint="--model")
    if out_path is not None and out_path.suffix.lower() not in (".csv", ".npy", ".json"):
        raise typer.BadParameter("expected a .csv, .npy or .json file", param_hint="--out")
    with _client(ctx) as c:
        r = c.reproduce(skill, point, model=model, outside=outside.value, goal=goal_point,
                        duration=duration, start_orientation=quat)
    if out_path is not None:
        _write_trajectory(out_path, r.positions, r, r.orientations)
    if _opts(ctx).json:
        _print_json({**_plain(r), "out": None if out_path is None else str(out_path)})
        return
    state = "inside" if r.inside else "outside, entering the canal" if r.projected \
        else "outside"
    end = ", ".join(f"{v:.4g}" for v in r.positions[-1])
    timing = "" if r.times is None else f" in {r.times[-1]:.3g} s"
    out.print(f"reproduced {len(r.positions)} points{timing} with model version {r.model_version}; "
              f"start {state} (eta {r.eta:.3f}, section {r.section_index}); ends at ({end})")
    if r.orientations is not None:
        last = ", ".join(f"{v:.4g}" for v in r.orientations[-1])
        out.print(f"with orientations; ends at qx,qy,qz,qw ({last})")
    for note in r.notes:
        out.print(f"note: {escape(note)}")
    if out_path is not None:
        out.print(f"wrote {escape(str(out_path))}")


# ---- recordings ------------------------------------------------------------------------------


@app.command()
def export(
    ctx: typer.Context,
    skill: str,
    rrd: Annotated[Path | None, typer.Option("--rrd", help="Save the Rerun recording here.")
                   ] = None,
    mcap: Annotated[Path | None, typer.Option("--mcap", help="Save the MCAP file here.")
                    ] = None,
    ros2: Annotated[bool, typer.Option(
        "--ros2", help="The MCAP as a rosbag2-compatible file (CDR) instead of Foxglove JSON.")
                    ] = False,
) -> None:
    """Download the skill's review recordings (both to ./SKILL.rrd and ./SKILL.mcap when
    neither --rrd nor --mcap is given)."""
    if rrd is None and mcap is None:
        rrd, mcap = Path(f"{skill}.rrd"), Path(f"{skill}.mcap")
    written: dict[str, str] = {}
    with _client(ctx) as c:
        for kind, path in (("rrd", rrd), ("mcap", mcap)):
            if path is not None:
                profile = "ros2" if kind == "mcap" and ros2 else None
                c.download_recording(skill, kind, path, profile=profile)  # type: ignore[arg-type]
                written[kind] = str(path)
                if not _opts(ctx).json:
                    out.print(f"wrote {escape(str(path))} ({path.stat().st_size} bytes)")
    if _opts(ctx).json:
        _print_json(written)


def _cache_dir() -> Path:
    if os.environ.get("CANAL_CACHE_DIR"):
        return Path(os.environ["CANAL_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "canal"


def rerun_command() -> list[str] | None:
    """The command that runs the Rerun viewer, or None when there is none here."""
    exe = shutil.which("rerun")
    if exe:
        return [exe]
    beside = Path(sys.executable).with_name("rerun.exe" if sys.platform == "win32" else "rerun")
    if beside.exists():
        return [str(beside)]
    try:
        import rerun_cli
    except ImportError:
        return None
    bundled = Path(rerun_cli.__file__).with_name(
        "rerun.exe" if sys.platform == "win32" else "rerun")
    return [str(bundled)] if bundled.exists() else [sys.executable, "-m", "rerun_cli"]


def has_display() -> bool:
    """Whether a GUI window can be opened here."""
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _spawn_detached(cmd: list[str]) -> None:
    kwargs: dict[str, Any] = {"stdin": subprocess.DEVNULL, "stdout": subprocess.DEVNULL,
                              "stderr": subprocess.DEVNULL, "close_fds": True}
    if sys.platform == "win32":
        kwargs["creationflags"] = (subprocess.DETACHED_PROCESS  # type: ignore[attr-defined]
                                   | subprocess.CREATE_NEW_PROCESS_GROUP)  # type: ignore[attr-defined]
    else:
        kwargs["start_new_session"] = True
    subprocess.Popen(cmd, **kwargs)


@app.command()
def view(
    ctx: typer.Context,
    skill: str,
    web: Annotated[bool, typer.Option(
        "--web", help="Open it in a browser: Rerun's web viewer, served by the service "
                      "(GET /skills/SKILL/view).")] = False,
    no_open: Annotated[bool, typer.Option("--no-open",
                                          help="Only download / print the link.")] = False,
) -> None:
    """Open the skill's recording in the Rerun viewer (downloaded to the cache folder,
    $CANAL_CACHE_DIR or ~/.cache/canal). With --web, print the service's web viewer link
    for the skill and open it in a browser. Without a viewer, a browser or a display, or with
    --no-open, prints the file's path (or the link) and how to open it."""
    if web:
        _view_web(ctx, skill, no_open)
        return
    path = _cache_dir() / f"{skill}.rrd"
    with _client(ctx) as c:
        c.download_recording(skill, "rrd", path)
    cmd = rerun_command()
    opts = _opts(ctx)
    opened = False
    if cmd is not None and has_display() and not no_open:
        try:
            _spawn_detached([*cmd, str(path)])
            opened = True
        except OSError as exc:
            _error(f"could not start the Rerun viewer: {exc}")
    open_cmd = shlex.join([*(cmd or ["rerun"]), str(path)])
    if opts.json:
        _print_json({"path": str(path), "opened": opened, "command": open_cmd})
        return
    if opened:
        out.print(f"opened {escape(str(path))} in the Rerun viewer")
        return
    out.print(f"recording saved to {escape(str(path))}")
    out.print(f"open it with: {escape(open_cmd)}")
    if cmd is None:
        out.print("(no Rerun viewer found: pip install rerun-sdk==0.41.0)")


def _view_web(ctx: typer.Context, skill: str, no_open: bool) -> None:
    """Check the skill can be viewed (exists, recordings on), then print and open its link."""
    import webbrowser
    from urllib.parse import quote

    opts = _opts(ctx)
    link = f"{opts.url.rstrip('/')}/skills/{quote(skill, safe='')}/view"
    with _client(ctx) as c:
        c.get_skill(skill)
        if (_health_json(opts).get("recorder") or {}).get("status") == "disabled":
            _error("recordings are disabled on this service (started with --no-recordings), "
                   "so there is nothing to view")
            raise typer.Exit(EXIT_REFUSED)
    opened = False
    if not no_open and has_display():
        with contextlib.suppress(webbrowser.Error):
            opened = webbrowser.open(link)
    if opts.json:
        _print_json({"url": link, "opened": opened})
        return
    out.print(f"{'opened' if opened else 'open'} {escape(link)}"
              + (" in your browser" if opened else " in a browser (Rerun's web viewer; the "
                 "first visit copies the viewer's files out of rerun-sdk, a few seconds)"))
@recordings_app.command("rebuild")
def recordings_rebuild(ctx: typer.Context, skill: str) -> None:
    """Regenerate SKILL's .rrd and .mcap from the service's database (demonstrations and
    model versions; live poses and reproductions are not stored, so they are not kept)."""
    with _client(ctx) as c:
        body = c.rebuild_recording(skill)
    if _opts(ctx).json:
        _print_json(body)
        return
    out.print(f"rebuilt the recordings of {escape(skill)}: {body.get('demos', 0)} "
              f"demonstrations, {body.get('models', 0)} model versions")


# ---- simulation ------------------------------------------------------------------------------


class Lag(StrEnum):
    first_order = "first-order"
    pd = "pd"


class Encoding(StrEnum):
    binary = "binary"
    json = "json"


def _parse_push(text: str) -> tuple[float | str, np.ndarray]:
    """``T:dx,dy[,dz]`` (seconds after the start) or ``P%:dx,dy[,dz]`` (progress along the canal)."""
    when_text, _, offset = text.partition(":")
    when_text = when_text.strip()
    when: float | str
    try:
        value = float(when_text[:-1] if when_text.endswith("%") else when_text)
    except ValueError:
        value = float("nan")
    if not offset or not np.isfinite(value) or value < 0 or (
            when_text.endswith("%") and value > 100):
        raise typer.BadParameter(f"expected T:dx,dy[,dz] (seconds) or P%:dx,dy[,dz] (progress) "
                                 f"like 1.5:0,0.05,0 or 50%:0,0.05,0, got {text!r}",
                                 param_hint="--push")
    when = when_text if when_text.endswith("%") else value
    return when, _parse_point(offset, "--push")


def _health_json(opts: Options) -> dict[str, Any]:
    """The service's /healthz document (also when it says 503 degraded: it still knows its
    bridge)."""
    import httpx

    try:
        response = httpx.get(opts.url.rstrip("/") + "/healthz", timeout=10.0)
    except httpx.TimeoutException:
        raise RequestTimeoutError(opts.url, 10.0) from None
    except httpx.TransportError as exc:
        raise ConnectionFailedError(opts.url, str(exc)) from None
    try:
        doc = response.json()
    except ValueError:
        doc = None
    if not isinstance(doc, dict):
        raise CanalClientError(f"{opts.url}/healthz did not answer like a Canal service "
                               f"(HTTP {response.status_code})")
    return doc


def live_endpoint(health: dict[str, Any], url: str) -> tuple[list[str], str]:
    """The Zenoh endpoints and key prefix a client should use, from the service's /healthz.

    The bridge reports the endpoints it listens on; one bound to every interface
    (``0.0.0.0`` / ``[::]``) is reached through the host of the service's URL."""
    from urllib.parse import urlsplit

    bridge = health.get("bridge") or {}
    if bridge.get("status") in (None, "disabled"):
        raise CanalClientError("the service at this --url runs no live bridge (started with "
                               "--no-zenoh?); pass --endpoint to reach another one")
    host = urlsplit(url).hostname or "127.0.0.1"
    endpoints = []
    for ep in bridge.get("listen") or []:
        for wildcard in ("0.0.0.0", "[::]"):
            if f"/{wildcard}:" in ep:
                ep = ep.replace(f"/{wildcard}:", f"/{host}:")
        endpoints.append(ep)
    if not endpoints:
        raise CanalClientError("the service's live bridge listens on no endpoint (it connects "
                               "to a router?); pass --endpoint or --zenoh-config")
    return endpoints, str(bridge.get("prefix") or "canal")


_SIM_SUMMARY = ("reached_end", "all_inside", "n_steps", "duration", "min_eta", "max_eta",
                "model_version", "start", "missed", "pushes_done", "pushes_pending", "statuses",
                "seed")


def _eta(result: Any, which: str) -> float:
    value = getattr(result, f"{which}_eta", None)
    return float("nan") if value is None else float(value)


@app.command()
def sim(
    ctx: typer.Context,
    skill: str,
    robot: Annotated[str | None, typer.Option("--robot", help="Robot id on the bus.")] = None,
    rate: Annotated[float | None, typer.Option("--rate", min=0.1, help="Control rate, Hz.")
                    ] = None,
    start: Annotated[str | None, typer.Option("--start", help="x,y[,z] start point.")] = None,
    lag: Annotated[Lag | None, typer.Option("--lag", help="Simulated robot dynamics.")] = None,
    gain: Annotated[float | None, typer.Option("--gain", help="Dynamics gain.")] = None,
    push: Annotated[list[str] | None, typer.Option(
        "--push", help="T:dx,dy,dz pushes the robot by (dx,dy,dz) at T s (repeat).")] = None,
    timeout: Annotated[float | None, typer.Option("--timeout", help="Give up after S s.")
                       ] = None,
    endpoint: Annotated[str | None, typer.Option(
        "--endpoint", help="Zenoh endpoint to connect to, e.g. tcp/127.0.0.1:7447 "
                           "(default: the one the service's /healthz reports).")] = None,
    prefix: Annotated[str | None, typer.Option(
        "--prefix", help="Zenoh key prefix (default: the service's, from /healthz).")] = None,
    zenoh_config: Annotated[Path | None, typer.Option("--zenoh-config",
                                                      help="Zenoh config file.")] = None,
    encoding: Annotated[Encoding | None, typer.Option("--encoding")] = None,
    seed: Annotated[int | None, typer.Option(
        "--seed", help="Seed of the random start (same seed, same start).")] = None,
) -> None:
    """Drive a simulated robot along the skill's canal over Zenoh. The Zenoh endpoint and
    key prefix come from the service at --url (its /healthz) unless --endpoint/--prefix or
    --zenoh-config say otherwise. Exit code 0 when the robot reached the end of the canal and
    stayed inside it, 1 otherwise; a push that never happened (the run ended first) is
    reported on its own line."""
    pushes = [_parse_push(p) for p in push or []]
    point = _parse_point(start) if start is not None else None
    try:
        from . import sim as sim_module
    except ImportError as exc:
        _error(f"the simulator is not available here: {exc}")
        raise typer.Exit(EXIT_REFUSED) from None
    opts = _opts(ctx)
    if (endpoint is None and zenoh_config is None) or prefix is None:
        try:
            found, found_prefix = live_endpoint(_health_json(opts), opts.url)
        except CanalClientError as exc:
            if endpoint is None and zenoh_config is None:
                if isinstance(exc, ConnectionFailedError | RequestTimeoutError):
                    raise _fail_unreachable(exc, opts.url) from None
                _error(str(exc))
                raise typer.Exit(EXIT_REFUSED) from None
            found, found_prefix = [], "canal"  # --endpoint given: the service is optional
        if endpoint is None and zenoh_config is None:
            endpoint = ",".join(found)
        prefix = prefix or found_prefix
    kwargs: dict[str, Any] = {"prefix": prefix, "pushes": pushes, "seed": seed}
    for key, value in (("robot", robot), ("start", point), ("rate_hz", rate),
                       ("lag", lag.value if lag else None), ("gain", gain),
                       ("timeout_s", timeout),
                       ("endpoint", endpoint.split(",") if endpoint else None),
                       ("zenoh_config", str(zenoh_config) if zenoh_config else None),
                       ("encoding", encoding.value if encoding else None)):
        if value is not None:
            kwargs[key] = value
    try:
        result = sim_module.run_sim(skill, **kwargs)
    except ApiError as exc:
        _error(str(exc))
        raise typer.Exit(EXIT_REFUSED) from None
    except (ConnectionFailedError, RequestTimeoutError) as exc:
        raise _fail_unreachable(exc, opts.url) from None
    except (CanalClientError, TimeoutError, OSError, ValueError, RuntimeError) as exc:
        _error(f"simulation failed: {exc}")
        raise typer.Exit(EXIT_REFUSED) from None
    ok = bool(result.reached_end) and bool(result.all_inside)
    if opts.json:
        _print_json({key: getattr(result, key, None) for key in _SIM_SUMMARY})
    else:
        out.print(
            f"{'[green]ok[/green]' if ok else '[red]failed[/red]'}: "
            f"{'reached the end' if result.reached_end else 'did not reach the end'}, "
            f"{'always inside' if result.all_inside else 'left the canal'}; "
            f"{result.n_steps} steps in {float(result.duration):.2f} s, "
            f"eta {_eta(result, 'min'):.3f}..{_eta(result, 'max'):.3f}")
        for line in sim_module.describe_pending(result):
            err.print(f"[yellow]note:[/yellow] {escape(line)}")
    if not ok:
        raise typer.Exit(EXIT_REFUSED)


def main() -> None:
    """Entry point (``canal``)."""
    app()


if __name__ == "__main__":
    app()
