"""``canal fit`` and ``canal reproduce``: model versions and the trajectories they give.

The choices and limits of the options are not written here: the fit choices are
canal_core's (:data:`canal_core.options.CROSS_SECTIONS`, ``FRAMES``, ``ALIGNMENTS``,
``DIRECTRICES``), the numeric limits and ``--outside`` are the HTTP contract's
(:class:`canal_protocol.schemas.FitRequest`, :class:`~canal_protocol.schemas.ReproductionRequest`),
so a kind or a limit added there shows up in ``canal fit --help`` by itself.
"""

from __future__ import annotations

import contextlib
import json
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from rich.markup import escape

from canal_core.options import ALIGNMENTS, CROSS_SECTIONS, DIRECTRICES, FRAMES
from canal_core.validation import FloatArray
from canal_protocol.options import (
    OUTSIDE_RULES,
    PERSISTENCES,
    Alignment,
    CrossSection,
    Directrix,
    FrameKind,
    Persistence,
)
from canal_protocol.options import OutsideRule as Outside
from canal_protocol.schemas import FitRequest

from .output import EXIT_REFUSED, err, error, out, plain, print_json
from .parsing import (
    choice_parser,
    contract_parser,
    expected_words,
    field_bounds,
    field_type,
    has_box,
    model_version,
    parse_obstacle,
    parse_point,
    parse_quaternion,
    stored_id,
)
from .session import connected, options

# typer shows each Literal's values as choices and choice_parser checks them (canal_protocol's
# aliases of canal_core's names: never written out here).

__all__ = ["field_bounds", "fit", "reproduce", "write_trajectory"]


SAMPLES_MIN, SAMPLES_MAX = field_bounds(FitRequest, "n_samples")
ROUTES_MIN, ROUTES_MAX = field_bounds(FitRequest, "routes")
SMOOTHING = field_type(FitRequest, "frame_smoothing")
SEPARATION = field_type(FitRequest, "route_separation")


def fit(
    ctx: typer.Context,
    skill: str,
    cross_section: Annotated[CrossSection | None, typer.Option(
        "--cross-section", "-c", parser=choice_parser(CROSS_SECTIONS))] = None,
    frames: Annotated[FrameKind | None, typer.Option(
        "--frames", parser=choice_parser(FRAMES))] = None,
    alignment: Annotated[Alignment | None, typer.Option(
        "--alignment", parser=choice_parser(ALIGNMENTS))] = None,
    directrix: Annotated[Directrix | None, typer.Option(
        "--directrix", parser=choice_parser(DIRECTRICES))] = None,
    samples: Annotated[int | None, typer.Option(
        "--samples", "-n", min=SAMPLES_MIN, max=SAMPLES_MAX,
        help="Sections along the canal.")] = None,
    frame_smoothing: Annotated[float | None, typer.Option(
        "--frame-smoothing", parser=contract_parser(SMOOTHING),
        help="Smooth the curve the frames are computed on (fraction of its length; "
             f"0 = the paper's raw frames; {expected_words(SMOOTHING)}).")] = None,
    by_time: Annotated[bool, typer.Option(
        "--by-time", help="Align by the demos' time stamps instead of arc length.")] = False,
    demo: Annotated[list[int] | None, typer.Option(
        "--demo", parser=stored_id, help="Fit only these demonstration ids (repeat).")] = None,
    drop_corrections: Annotated[bool, typer.Option(
        "--drop-corrections", help="Leave the skill's corrections behind (by default they "
        "are re-applied to the new canal, as a version of its own).")] = False,
    routes: Annotated[int | None, typer.Option(
        "--routes", min=ROUTES_MIN, max=ROUTES_MAX,
        help="Routes (one canal each): 1 = one canal of all the demonstrations; N = exactly "
             "N; left out: demonstrations that go clearly different ways are split.")] = None,
    route_separation: Annotated[float | None, typer.Option(
        "--route-separation", parser=contract_parser(SEPARATION),
        help="Where routes split when --routes is left out: the demonstrations' mean "
             f"distance as a share of their median path length ({expected_words(SEPARATION)}).")
    ] = None,
) -> None:
    """Fit a new model version from the skill's demonstrations (service defaults otherwise)."""
    busy = (contextlib.nullcontext() if options(ctx).json
            else err.status(f"fitting {escape(skill)}..."))
    with connected(ctx) as c, busy:
        model = c.fit(skill, cross_section=cross_section, frames=frames, alignment=alignment,
                      directrix=directrix, n_samples=samples, frame_smoothing=frame_smoothing,
                      by_time=by_time or None, demo_ids=demo or None,
                      keep_corrections=False if drop_corrections else None, routes=routes,
                      route_separation=route_separation)
    if options(ctx).json:
        print_json(model)
        return
    out.print(f"fitted {escape(skill)}: version [bold]{model.version}[/bold], "
              f"{model.n_demos} demos, {model.n_sections} {model.section_kind} sections, "
              f"{model.fit_seconds:.3f} s")
    if model.routes > 1 and model.demo_routes is not None:
        members = [[str(i) for i, r in zip(model.demo_ids, model.demo_routes, strict=True) if r == k]
                   for k in range(model.routes)]
        split = "; ".join(f"route {k}: demo{'s' if len(m) > 1 else ''} {', '.join(m)}"
                          for k, m in enumerate(members))
        out.print(f"{model.routes} routes, one canal each ({split})")
    if model.corrections:
        out.print(f"corrections {', '.join(map(str, model.corrections))} re-applied (version "
                  f"{model.version}, parent {model.parent_version})")
    for note in model.notes:
        out.print(f"note: {escape(note)}")


def write_trajectory(path: Path, positions: FloatArray, payload: Any,
                     orientations: FloatArray | None = None,
                     times: FloatArray | None = None) -> None:
    """Save a reproduction: .csv (a ``t`` column of seconds when the model is timed, then
    x,y[,z], then qx..qw with orientations), .npy (positions only) or .json (``payload``, the
    whole reproduction)."""
    suffix = path.suffix.lower()
    path.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".csv":
        header = "x,y,z" if positions.shape[1] == 3 else "x,y"
        table = positions
        if times is not None:
            header, table = "t," + header, np.column_stack([times, table])
        if orientations is not None:
            header, table = header + ",qx,qy,qz,qw", np.hstack([table, orientations])
        np.savetxt(path, table, delimiter=",", header=header, comments="", fmt="%.17g")
    elif suffix == ".npy":
        np.save(path, positions)
    else:
        path.write_text(json.dumps(plain(payload), indent=2) + "\n")


def reproduce(
    ctx: typer.Context,
    skill: str,
    start: Annotated[str, typer.Option("--start", "-s", help="x,y[,z] start point.")],
    model: Annotated[str, typer.Option("--model", "-m", parser=model_version,
                                       help="Model version or 'latest'.")] = "latest",
    out_path: Annotated[Path | None, typer.Option(
        "--out", "-o", help="Save the trajectory: .csv (t,x,y,z header; t in seconds when the "
        "model is timed), .npy (N, D positions) or .json (with times and velocities).")
    ] = None,
    outside: Annotated[Outside, typer.Option(
        "--outside", parser=choice_parser(OUTSIDE_RULES),
        help="A start outside the canal: enter the canal over a short blend, or refuse.")
    ] = OUTSIDE_RULES[0],
    start_orientation: Annotated[str | None, typer.Option(
        "--start-orientation", "-q",
        help="qx,qy,qz,qw unit quaternion of the start pose (models with orientation carry it; "
             "--out .csv then adds qx,qy,qz,qw columns).")] = None,
    goal: Annotated[str | None, typer.Option(
        "--goal", "-g", help="x,y[,z] goal: the canal is deformed to end there.")] = None,
    duration: Annotated[float | None, typer.Option(
        "--duration", "-d", help="Seconds: stretch the reproduction's times to end there.")
    ] = None,
    obstacle: Annotated[list[str] | None, typer.Option(
        "--obstacle", help="sphere:x,y,z,r[,clearance] (also box:, capsule:, disc:; repeat): "
                           "go around it too (added to the skill's scene for this run).")
    ] = None,
    route: Annotated[int | None, typer.Option(
        "--route", min=0, help="A model of several routes: follow this route (default: the "
                               "route whose entry holds the start).")] = None,
    persistence: Annotated[Persistence, typer.Option(
        "--persistence", parser=choice_parser(PERSISTENCES),
        help="How the start's offset is carried: learned (what the demonstrations kept, faded "
             "onto the canal's end), constant (the paper's rule), learned+end (kept to the end: "
             "end where the demonstrations' ends follow their starts).")] = PERSISTENCES[0],
) -> None:
    """Reproduce a trajectory from a new start (optionally to a new goal, in a given time,
    around obstacles)."""
    point = parse_point(start)
    obstacles = [parse_obstacle(o) for o in obstacle or []] or None
    quat = None if start_orientation is None else parse_quaternion(start_orientation)
    goal_point = None if goal is None else parse_point(goal, "--goal")
    if duration is not None and not (np.isfinite(duration) and duration > 0):
        raise typer.BadParameter(f"expected seconds > 0, got {duration}", param_hint="--duration")
    if out_path is not None and out_path.suffix.lower() not in (".csv", ".npy", ".json"):
        raise typer.BadParameter("expected a .csv, .npy or .json file", param_hint="--out")
    with connected(ctx) as c:
        if has_box(obstacle):  # a box's numbers are read by the skill's dimension
            dim = c.get_skill(skill).dim
            obstacles = [parse_obstacle(o, dim=dim) for o in obstacle or []]
        r = c.reproduce(skill, point, model=model, outside=outside, goal=goal_point,
                        duration=duration, start_orientation=quat, obstacles=obstacles,
                        route=route, persistence=persistence)
    if out_path is not None:
        try:
            write_trajectory(out_path, r.positions, r, r.orientations, r.times)
        except OSError as exc:
            error(f"cannot write {out_path}: {exc.strerror or exc}")
            raise typer.Exit(EXIT_REFUSED) from None
    if options(ctx).json:
        print_json({**plain(r), "out": None if out_path is None else str(out_path)})
        return
    state = "inside" if r.inside else "outside, entering the canal" if r.projected \
        else "outside"
    end = ", ".join(f"{v:.4g}" for v in r.positions[-1])
    # the trajectory's own duration (the model's timing), not how long computing it took
    lasts = ("; the model is untimed (no time stamps)" if r.times is None
             else f"; the trajectory lasts {r.times[-1] - r.times[0]:.3g} s")
    out.print(f"reproduced {len(r.positions)} points with model version {r.model_version}"
              f"{lasts}; start {state} (eta {r.eta:.3f}, section {r.section_index}); "
              f"ends at ({end})")
    if len(r.ratios):
        # named points only where the path has that many (a path of 2 has a start and an end)
        names = (("start", "end") if len(r.ratios) < 5
                 else ("start", "a quarter", "half-way", "three quarters", "end"))
        marks = np.linspace(0, len(r.ratios) - 1, len(names)).round().astype(int)
        out.print("how far out, as a share of the canal's reach (0 the directrix, 1 the wall): "
                  + ", ".join(f"{name} {r.ratios[i]:.2f}" for name, i in zip(names, marks, strict=True)))
    if r.approach:
        out.print(f"the start is farther from the path than the demonstrations stepped: {r.approach} points "
                  "approach it in a straight line, paced like the demonstrations' steps")
    if r.route is not None or r.route_reason not in (None, "single"):
        which = "the canal of all routes" if r.route is None else f"route {r.route}"
        out.print(f"followed {which} ({r.route_reason})")
    if r.orientations is not None:
        last = ", ".join(f"{v:.4g}" for v in r.orientations[-1])
        out.print(f"with orientations; ends at qx,qy,qz,qw ({last})")
    if r.obstacles:
        out.print(f"around {r.obstacles} obstacle{'s' if r.obstacles > 1 else ''}"
                  + ("" if r.scene_version is None else f" (scene version {r.scene_version})"))
    if r.blocked is not None:
        out.print(f"[yellow]blocked[/yellow] at section {r.blocked.section} ({r.blocked.reason}, "
                  f"obstacles {r.blocked.obstacles}): the trajectory stops before it")
    for note in r.notes:
        out.print(f"note: {escape(note)}")
    if out_path is not None:
        out.print(f"wrote {escape(str(out_path))}")
