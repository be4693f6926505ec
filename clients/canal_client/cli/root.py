"""The ``canal`` command: global options, then the command groups in the order
``canal --help`` lists them."""

from __future__ import annotations

from typing import Any

import pydantic
import typer
from typer.core import TyperGroup

from . import corrections, demos, models, recordings, scenes, serve, simulation, skills
from .session import global_options

HELP = """Canal: learn robot skills from demonstrations with canal surfaces.

\b
  canal serve [service flags]             run the service here
  canal skill create|list|show|delete     skills
  canal demo add SKILL FILE_OR_FOLDER...  demonstrations (.csv, .npy, .json, .mcap)
  canal demo list|rm SKILL                look at / remove demonstrations
  canal fit SKILL [--cross-section ...]   fit a new model version
  canal reproduce SKILL --start x,y,z     a new trajectory (--out traj.csv)
  canal scene set|show|clear SKILL        obstacles every reproduction goes around
  canal correct SKILL FILE --kind exclude refine the canal by a correction (a new version)
  canal corrections list|undo SKILL       a skill's corrections; undo one
  canal export SKILL [--rrd F] [--mcap F] download the review recordings
  canal view SKILL [--web]                open the recording in the Rerun viewer
  canal recordings rebuild SKILL          regenerate the recordings from the database
  canal sim SKILL                         drive a simulated robot (Zenoh)

Global options go before the command: canal --url http://host:8000 --token T skill list
(or CANAL_URL / CANAL_TOKEN).

Exit codes: 0 success; 1 the service refused something (its message is printed) or a
simulation that did not end inside the canal; 2 bad usage; 3 the service cannot be reached.
"""


def refusal_with_what_came(exc: typer.BadParameter) -> typer.BadParameter:
    """typer's conversion of a typed value (a number, a path) words its refusal as pydantic
    does, without the value: "Input should be a valid integer, unable to parse string as an
    integer". The same refusal with ", got 'abc'", as the service words one over REST."""
    cause = exc.__cause__
    if not isinstance(cause, pydantic.ValidationError) or not cause.errors():
        return exc
    got = cause.errors()[0].get("input")
    shown = repr(got) if isinstance(got, str) else str(got)
    return typer.BadParameter(f"{exc.message}, got {shown}", ctx=exc.ctx, param=exc.param,
                              param_hint=exc.param_hint)


class CanalGroup(TyperGroup):
    """The root command: every subcommand's usage error says what was typed."""

    def invoke(self, ctx: Any) -> Any:  # typer's vendored click Context
        try:
            return super().invoke(ctx)
        except typer.BadParameter as exc:
            raise refusal_with_what_came(exc) from exc.__cause__


app = typer.Typer(name="canal", help=HELP, no_args_is_help=True, add_completion=False,
                  rich_markup_mode=None, pretty_exceptions_enable=False, cls=CanalGroup)
app.callback()(global_options)
# serve hands every argument, --help included, to the service's own parser
app.command(context_settings={"allow_extra_args": True, "ignore_unknown_options": True,
                              "help_option_names": []})(serve.serve)
app.command()(models.fit)
app.command()(models.reproduce)
app.command()(corrections.correct)
app.command()(recordings.export)
app.command()(recordings.view)
app.command()(simulation.sim)
app.add_typer(skills.app, name="skill")
app.add_typer(demos.app, name="demo")
app.add_typer(corrections.app, name="corrections")
app.add_typer(recordings.app, name="recordings")
app.add_typer(scenes.app, name="scene")


def main() -> None:
    """Entry point (``canal``)."""
    app()
