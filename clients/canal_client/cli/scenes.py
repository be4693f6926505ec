"""``canal scene set|show|clear``: the obstacles a skill's reproductions and live streams go around."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.markup import escape

from .output import out, print_json
from .parsing import existing_file, has_box, parse_obstacle
from .session import connected, options

app = typer.Typer(help="Set, show and clear a skill's scene (its obstacles).", no_args_is_help=True)


def read_scene_file(path: Path) -> list[dict[str, Any]]:
    """A scene file: JSON ``{"obstacles": [...]}`` or a bare list of obstacles."""
    existing_file(path, "SCENE")  # a pipe would wait for a writer for ever
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise typer.BadParameter(f"expected a readable JSON file, got {exc}", param_hint="SCENE") from None
    items = data.get("obstacles") if isinstance(data, dict) else data
    if not isinstance(items, list):
        raise typer.BadParameter('expected {"obstacles": [...]} or a list of obstacles',
                                 param_hint="SCENE")
    return items


def _describe(scene: Any) -> str:
    kinds: dict[str, int] = {}
    for o in scene.obstacles:
        kinds[str(o.get("kind"))] = kinds.get(str(o.get("kind")), 0) + 1
    listed = ", ".join(f"{n} {k}{'s' if n > 1 else ''}" for k, n in sorted(kinds.items())) or "no obstacles"
    return f"scene of [bold]{escape(scene.skill)}[/bold] version {scene.version}: {listed}"


@app.command("set")
def scene_set(
    ctx: typer.Context,
    skill: str,
    scene: Annotated[Path | None, typer.Argument(
        help='JSON file: {"obstacles": [...]} (see docs/obstacles.md).')] = None,
    obstacle: Annotated[list[str] | None, typer.Option(
        "--obstacle", help="sphere:x,y,z,r[,clearance], box:cx,cy,cz,hx,hy,hz, "
                           "capsule:ax,ay,az,bx,by,bz,r, disc:x,y,r (repeat; added to the file's).")
    ] = None,
) -> None:
    """Replace the skill's scene: every later reproduction, and every live stream from its
    next pose, goes around these obstacles."""
    if scene is None and not obstacle:
        # A forgotten file must not remove every obstacle without a word.
        raise typer.BadParameter("expected a scene file or --obstacle; to remove every obstacle: "
                                 "canal scene clear SKILL", param_hint="SCENE")
    items = read_scene_file(scene) if scene is not None else []
    typed = [parse_obstacle(o) for o in obstacle or []]
    with connected(ctx) as c:
        if has_box(obstacle):  # a box's numbers are read by the skill's dimension
            dim = c.get_skill(skill).dim
            typed = [parse_obstacle(o, dim=dim) for o in obstacle or []]
        result = c.set_scene(skill, items + typed)
    if options(ctx).json:
        print_json(result)
    else:
        out.print(_describe(result))


@app.command("show")
def scene_show(ctx: typer.Context, skill: str) -> None:
    """The skill's scene."""
    with connected(ctx) as c:
        result = c.get_scene(skill)
    if options(ctx).json:
        print_json(result)
        return
    out.print(_describe(result))
    for i, o in enumerate(result.obstacles):
        out.print(f"  [{i}] {escape(json.dumps(o))}")


@app.command("clear")
def scene_clear(ctx: typer.Context, skill: str) -> None:
    """Remove every obstacle from the skill's scene."""
    with connected(ctx) as c:
        c.clear_scene(skill)
        result = c.get_scene(skill)
    if options(ctx).json:
        print_json(result)
    else:
        out.print(_describe(result))
