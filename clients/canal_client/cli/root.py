"""The ``canal`` command: global options, then the command groups in the order
``canal --help`` lists them."""

from __future__ import annotations

import typer

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

app = typer.Typer(name="canal", help=HELP, no_args_is_help=True, add_completion=False,
                  rich_markup_mode=None, pretty_exceptions_enable=False)
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
