"""``canal sim``: a simulated robot driven along a skill's canal over Zenoh
(:func:`canal_client.sim.run_sim`)."""

from __future__ import annotations

import importlib.util
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any
from urllib.parse import urlsplit

import numpy as np
import typer
from rich.markup import escape

from canal_core.bounds import MAX_COORDINATE
from canal_core.validation import FloatArray
from canal_protocol import keys
from canal_protocol.keys import check_chunk

from ..errors import (
    ApiError,
    ArgumentError,
    CanalClientError,
    ConnectionFailedError,
    RequestTimeoutError,
    UnauthorizedError,
)
from ..rest import CanalClient
from .output import EXIT_REFUSED, err, error, out, print_json
from .parsing import choice_parser, parse_obstacle, parse_point
from .session import connected, fail_unreachable, health_document, options

#: What ``canal sim`` needs beyond the REST client, and how to get it.
ZENOH_MODULE = "zenoh"
ZENOH_INSTALL = "pip install eclipse-zenoh==1.10.2"


class Lag(StrEnum):
    first_order = "first-order"
    pd = "pd"


class Encoding(StrEnum):
    binary = "binary"
    json = "json"


def parse_push(text: str) -> tuple[float | str, FloatArray]:
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
    push = parse_point(offset, "--push")
    if not np.all(np.abs(push) <= MAX_COORDINATE):
        raise typer.BadParameter(f"expected an offset of coordinates within +-{MAX_COORDINATE:g} "
                                 f"(a pose's), got {text!r}", param_hint="--push")
    return when, push


def parse_prefix(text: str) -> str:
    """A Zenoh key prefix of plain chunks (:func:`canal_protocol.keys.check_prefix`)."""
    try:
        return keys.check_prefix(text)
    except ValueError as exc:
        raise typer.BadParameter(str(exc), param_hint="--prefix") from None


def live_endpoint(health: dict[str, Any], url: str) -> tuple[list[str], str]:
    """The Zenoh endpoints and key prefix a client should use, from the service's /healthz.

    The bridge reports the endpoints it listens on; one bound to every interface
    (``0.0.0.0`` / ``[::]``) is reached through the host of the service's URL."""
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
                "model_version", "start", "missed", "pushes_done", "pushes", "pushes_pending",
                "statuses", "seed", "held", "corrections", "refused")


def parse_keep_out(text: str) -> tuple[FloatArray, float]:
    """``x,y,z:r`` as (centre, radius > 0)."""
    centre, sep, radius = text.rpartition(":")
    try:
        r = float(radius)
    except ValueError:
        r = float("nan")
    if not sep or not (r > 0 and np.isfinite(r)):
        raise typer.BadParameter(f"expected x,y,z:r with r > 0, got {text!r}",
                                 param_hint="--keep-out")
    return parse_point(centre, "--keep-out"), r


#: run_sim's parameters as this command's flags, for the errors it raises.
_FLAGS = {"start": "--start", "pushes": "--push", "keep_out": "--keep-out", "gain": "--gain",
          "timeout_s": "--timeout", "rate_hz": "--rate", "endpoint": "--endpoint",
          "zenoh_config": "--zenoh-config"}


def _flag_error(exc: Any) -> typer.BadParameter:
    """A ``SimInputError`` as the usage error of the flag that gave the value."""
    return typer.BadParameter(str(exc), param_hint=_FLAGS.get(exc.param, exc.param))


def token_refusal(ctx: typer.Context, skill: str, health: dict[str, Any] | None) -> str | None:
    """Why the service's live path refused a session that reached no Zenoh node, when its
    /healthz says the path admits only sessions that give its token (``bridge.access``): no
    --token, or one the service refuses (asked of its REST API, which takes the same token).
    None when that is not it."""
    opts = options(ctx)
    if health is None:
        try:
            health = health_document(opts)
        except CanalClientError:
            return None
    if (health.get("bridge") or {}).get("access") != "authenticated":
        return None
    if not opts.token:
        return ("the service's live path admits only sessions that give its token: pass it "
                "with --token (CANAL_TOKEN)")
    try:
        with CanalClient(opts.url, token=opts.token, timeout=10.0) as c:
            c.get_skill(skill)
    except UnauthorizedError as exc:
        return f"the service refused the token given (--token): {exc}"
    except CanalClientError:
        pass
    return None


def _eta(result: Any, which: str) -> float:
    value = getattr(result, f"{which}_eta", None)
    return float("nan") if value is None else float(value)


def sim(
    ctx: typer.Context,
    skill: str,
    robot: Annotated[str | None, typer.Option("--robot", help="Robot id on the bus.")] = None,
    rate: Annotated[float | None, typer.Option("--rate", min=0.1, help="Control rate, Hz.")
                    ] = None,
    start: Annotated[str | None, typer.Option("--start", help="x,y[,z] start point.")] = None,
    lag: Annotated[Lag | None, typer.Option(
        "--lag", parser=choice_parser(list(Lag)), help="Simulated robot dynamics.")] = None,
    gain: Annotated[float | None, typer.Option("--gain", help="Dynamics gain.")] = None,
    push: Annotated[list[str] | None, typer.Option(
        "--push", help="T:dx,dy,dz pushes the robot by (dx,dy,dz) at T s (repeat).")] = None,
    timeout: Annotated[float | None, typer.Option(
        "--timeout", help="Give up after S s (default 60). Before the run, the bridge and "
                          "then the model are each waited for at most 5 s, or S s when less."
    )] = None,
    endpoint: Annotated[str | None, typer.Option(
        "--endpoint", help="Zenoh endpoint to connect to, e.g. tcp/127.0.0.1:7447, several "
                           "comma-separated (default: the ones the service's /healthz "
                           "reports).")] = None,
    prefix: Annotated[str | None, typer.Option(
        "--prefix", parser=parse_prefix,
        help="Zenoh key prefix (default: the service's, from /healthz).")] = None,
    zenoh_config: Annotated[Path | None, typer.Option("--zenoh-config",
                                                      help="Zenoh config file.")] = None,
    encoding: Annotated[Encoding | None, typer.Option(
        "--encoding", parser=choice_parser(list(Encoding)))] = None,
    seed: Annotated[int | None, typer.Option(
        "--seed", help="Seed of the random start (same seed, same start).")] = None,
    obstacle: Annotated[list[str] | None, typer.Option(
        "--obstacle", help="sphere:x,y,z,r[,clearance] (also box:, capsule:, disc:; repeat): "
                           "set the skill's scene to these before the run (it stays set; "
                           "canal scene clear removes it).")] = None,
    keep_out: Annotated[str | None, typer.Option(
        "--keep-out", help="x,y,z:r a keep-out sphere the canal does not know: a simulated "
        "person holds the robot out of it and sends the push as an exclude correction.")
    ] = None,
) -> None:
    """Drive a simulated robot along the skill's canal over Zenoh. The Zenoh endpoint and
    key prefix come from the service at --url (its /healthz) unless --endpoint/--prefix or
    --zenoh-config say otherwise. Exit code 0 when the robot reached the end of the canal and
    stayed inside it, 1 otherwise; a push that never happened (the run ended first) is
    reported on its own line."""
    pushes = [parse_push(p) for p in push or []]
    point = parse_point(start) if start is not None else None
    obstacles = [parse_obstacle(o) for o in obstacle or []]
    sphere = None if keep_out is None else parse_keep_out(keep_out)
    if importlib.util.find_spec(ZENOH_MODULE) is None:
        error(f"canal sim talks to the service over Zenoh, which is not installed here: "
              f"{ZENOH_INSTALL}")
        raise typer.Exit(EXIT_REFUSED)
    from .. import sim as sim_module  # imports zenoh: only for this command
    from ..live import NoBridgeError, client_config

    endpoints = None if endpoint is None else [e.strip() for e in endpoint.split(",")]
    if robot is not None:
        try:
            check_chunk(robot, "robot")
        except ValueError as exc:
            raise typer.BadParameter(str(exc), param_hint="--robot") from None
    try:  # before anything is asked of the service: a value Zenoh cannot use at all
        if endpoints is not None:
            client_config(endpoints)
        if zenoh_config is not None:
            client_config(zenoh_config=zenoh_config)
    except ArgumentError as exc:
        raise typer.BadParameter(f"expected {exc.expected}, got {exc.got}",
                                 param_hint=_FLAGS.get(exc.argument, exc.argument)) from None
    opts = options(ctx)
    health: dict[str, Any] | None = None
    if (endpoint is None and zenoh_config is None) or prefix is None:
        try:
            health = health_document(opts)
            found, found_prefix = live_endpoint(health, opts.url)
        except CanalClientError as exc:
            if endpoint is None and zenoh_config is None:
                if isinstance(exc, ConnectionFailedError | RequestTimeoutError):
                    raise fail_unreachable(exc, opts.url) from None
                error(str(exc))
                raise typer.Exit(EXIT_REFUSED) from None
            found, found_prefix = [], "canal"  # --endpoint given: the service is optional
        if endpoints is None and zenoh_config is None:
            endpoints = found
        prefix = prefix or found_prefix
    try:
        # before the scene is set: a run refused afterwards would have changed it
        sim_module.check_run(**{k: v for k, v in (("rate_hz", rate), ("timeout_s", timeout),
                                                   ("gain", gain)) if v is not None})
        if obstacles:
            with connected(ctx) as c:
                dim = c.get_skill(skill).dim
                sim_module.check_points(dim, point, pushes, sphere)
            # a box's numbers are read by the skill's dimension
            obstacles = [parse_obstacle(o, dim=dim) for o in obstacle or []]
    except sim_module.SimInputError as exc:
        raise _flag_error(exc) from None
    if obstacles:
        with connected(ctx) as c:
            scene = c.set_scene(skill, obstacles)
        out.print(f"scene of {escape(skill)} set (version {scene.version}, "
                  f"{len(scene.obstacles)} obstacles)")
    kwargs: dict[str, Any] = {"prefix": prefix, "pushes": pushes, "seed": seed,
                              "token": opts.token, "keep_out": sphere}
    for key, value in (("robot", robot), ("start", point), ("rate_hz", rate),
                       ("lag", lag.value if lag else None), ("gain", gain),
                       ("timeout_s", timeout),
                       ("endpoint", endpoints),
                       ("zenoh_config", str(zenoh_config) if zenoh_config else None),
                       ("encoding", encoding.value if encoding else None)):
        if value is not None:
            kwargs[key] = value
    try:
        result = sim_module.run_sim(skill, **kwargs)
    except sim_module.SimInputError as exc:
        raise _flag_error(exc) from None
    except ApiError as exc:
        error(str(exc))
        raise typer.Exit(EXIT_REFUSED) from None
    except (ConnectionFailedError, RequestTimeoutError) as exc:
        raise fail_unreachable(exc, opts.url) from None
    except NoBridgeError as exc:
        # a token is no part of a --zenoh-config session: its file says its own credentials
        refusal = None if exc.reached or zenoh_config else token_refusal(ctx, skill, health)
        error(f"simulation failed: {refusal or exc}")
        raise typer.Exit(EXIT_REFUSED) from None
    except (CanalClientError, TimeoutError, OSError, ValueError, RuntimeError) as exc:
        error(f"simulation failed: {exc}")
        raise typer.Exit(EXIT_REFUSED) from None
    ok = bool(result.reached_end) and bool(result.all_inside)
    if opts.json:
        print_json({key: getattr(result, key, None) for key in _SIM_SUMMARY})
    else:
        out.print(
            f"{'[green]ok[/green]' if ok else '[red]failed[/red]'}: "
            f"{'reached the end' if result.reached_end else 'did not reach the end'}, "
            f"{'always inside' if result.all_inside else 'left the canal'}; "
            f"{result.n_steps} steps in {float(result.duration):.2f} s, "
            f"eta {_eta(result, 'min'):.3f}..{_eta(result, 'max'):.3f}")
        for push_done in result.pushes:
            out.print(escape(sim_module.describe_push(push_done)))
        around = {k: v for k, v in result.statuses.items() if k in ("detour", "blocked", "in_obstacle")}
        if around:
            out.print("obstacles: " + ", ".join(f"{v} {k}" for k, v in sorted(around.items())))
        for line in sim_module.describe_pending(result):
            out.print(escape(line))
        if sphere is not None:
            made = ", ".join(map(str, result.corrections)) or "none"
            out.print(f"keep-out: held out of the sphere for {result.held} steps; "
                      f"exclude corrections made model versions {made}")
            for why in result.refused:
                err.print(f"[yellow]note:[/yellow] correction refused: {escape(why)}")
    if not ok:
        raise typer.Exit(EXIT_REFUSED)
