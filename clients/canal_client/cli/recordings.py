"""``canal export``, ``canal view`` and ``canal recordings rebuild``: the service's review
recordings (.rrd for the Rerun viewer, .mcap for Foxglove / ROS 2)."""

from __future__ import annotations

import contextlib
import importlib.util
import os
import shlex
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Annotated, Any, Literal

import typer
from rich.markup import escape

from ..rest import CanalClient
from .output import EXIT_REFUSED, error, out, print_json
from .session import connected, health_document, options

app = typer.Typer(help="The service's review recordings.", no_args_is_help=True)


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
    wanted: tuple[tuple[Literal["rrd", "mcap"], Path | None], ...] = (("rrd", rrd), ("mcap", mcap))
    with connected(ctx) as c:
        for kind, path in wanted:
            if path is None:
                continue
            if path.is_dir():  # a folder is where the file goes, as for cp
                path = path / f"{skill}.{kind}"
            save(c, skill, kind, path, profile="ros2" if ros2 and kind == "mcap" else None)
            written[kind] = str(path)
            if not options(ctx).json:
                out.print(f"wrote {escape(str(path))} ({path.stat().st_size} bytes)")
    if options(ctx).json:
        print_json(written)


def save(c: CanalClient, skill: str, kind: Literal["rrd", "mcap"], path: Path, *,
         profile: str | None = None, hint: str = "") -> None:
    """Download the skill's recording to ``path``; a path that cannot be written is a
    one-line error (``hint``: what to change), exit code 1."""
    try:
        c.download_recording(skill, kind, path, profile=profile)
    except OSError as exc:
        error(f"cannot write {path}: {exc.strerror or exc}{hint}")
        raise typer.Exit(EXIT_REFUSED) from None


def cache_dir() -> Path:
    """Where ``canal view`` keeps the recordings it downloads."""
    if os.environ.get("CANAL_CACHE_DIR"):
        return Path(os.environ["CANAL_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "canal"


def rerun_command() -> list[str] | None:
    """The command that runs the Rerun viewer, or None when there is none here (rerun-sdk is
    the service's dependency; a client-only install may not have it)."""
    exe_name = "rerun.exe" if sys.platform == "win32" else "rerun"
    exe = shutil.which("rerun")
    if exe:
        return [exe]
    beside = Path(sys.executable).with_name(exe_name)
    if beside.exists():
        return [str(beside)]
    spec = importlib.util.find_spec("rerun_cli")
    if spec is None or spec.origin is None:
        return None
    bundled = Path(spec.origin).with_name(exe_name)
    return [str(bundled)] if bundled.exists() else [sys.executable, "-m", "rerun_cli"]


def has_display() -> bool:
    """Whether a GUI window can be opened here."""
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def spawn_detached(cmd: list[str]) -> None:
    """Start ``cmd`` so that it outlives this command (the viewer stays open)."""
    kwargs: dict[str, Any] = {"stdin": subprocess.DEVNULL, "stdout": subprocess.DEVNULL,
                              "stderr": subprocess.DEVNULL, "close_fds": True}
    if sys.platform == "win32":
        kwargs["creationflags"] = (getattr(subprocess, "DETACHED_PROCESS", 0)
                                   | getattr(subprocess, "CREATE_NEW_PROCESS_GROUP", 0))
    else:
        kwargs["start_new_session"] = True
    subprocess.Popen(cmd, **kwargs)


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
        view_web(ctx, skill, no_open)
        return
    path = cache_dir() / f"{skill}.rrd"
    with connected(ctx) as c:
        save(c, skill, "rrd", path, hint=" (the download folder: set CANAL_CACHE_DIR to a "
             "folder that can be written)")
    cmd = rerun_command()
    opts = options(ctx)
    opened = False
    if cmd is not None and has_display() and not no_open:
        try:
            spawn_detached([*cmd, str(path)])
            opened = True
        except OSError as exc:
            error(f"could not start the Rerun viewer: {exc}")
    open_cmd = shlex.join([*(cmd or ["rerun"]), str(path)])
    if opts.json:
        print_json({"path": str(path), "opened": opened, "command": open_cmd})
        return
    if opened:
        out.print(f"opened {escape(str(path))} in the Rerun viewer")
        return
    out.print(f"recording saved to {escape(str(path))}")
    out.print(f"open it with: {escape(open_cmd)}")
    if cmd is None:
        out.print("(no Rerun viewer found: pip install rerun-sdk==0.41.0)")


def view_web(ctx: typer.Context, skill: str, no_open: bool) -> None:
    """Check the skill can be viewed (exists, recordings on), then print and open its link."""
    import webbrowser
    from urllib.parse import quote

    opts = options(ctx)
    link = f"{opts.url.rstrip('/')}/skills/{quote(skill, safe='')}/view"
    with connected(ctx) as c:
        c.get_skill(skill)
        if (health_document(opts).get("recorder") or {}).get("status") == "disabled":
            error("recordings are disabled on this service (started with --no-recordings), "
                  "so there is nothing to view")
            raise typer.Exit(EXIT_REFUSED)
    opened = False
    if not no_open and has_display():
        with contextlib.suppress(webbrowser.Error):
            opened = webbrowser.open(link)
    if opts.json:
        print_json({"url": link, "opened": opened})
        return
    out.print(f"{'opened' if opened else 'open'} {escape(link)}"
              + (" in your browser" if opened else " in a browser (Rerun's web viewer; the "
                 "first visit copies the viewer's files out of rerun-sdk, a few seconds)"))


@app.command("rebuild")
def recordings_rebuild(ctx: typer.Context, skill: str) -> None:
    """Regenerate SKILL's .rrd and .mcap from the service's database: its demonstrations,
    model versions and the reproductions it keeps (the service's
    --recordings-reproductions-kept, the newest per skill). Live poses are not stored, so a
    rebuilt recording does not have them."""
    with connected(ctx) as c:
        body = c.rebuild_recording(skill)
    if options(ctx).json:
        print_json(body)
        return
    out.print(f"rebuilt the recordings of {escape(skill)}: {body.get('demos', 0)} "
              f"demonstrations, {body.get('models', 0)} model versions, "
              f"{body.get('reproductions', 0)} reproductions")
