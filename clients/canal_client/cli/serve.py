"""``canal serve``: run the Canal service here.

The command line does not import the service (the client is installable without it): it
becomes ``python -m canal_service ARGS`` in the same Python (``os.execv``), so the service's
flags, signals and exit codes are its own."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys

import typer
from rich.markup import escape

from .output import EXIT_REFUSED, err, error

SERVICE_MODULE = "canal_service"
#: How to get the service when only the client is installed.
SERVICE_INSTALL = "pip install 'canal-lfd[service]'"


def service_command(args: list[str]) -> list[str]:
    """The command ``canal serve ARGS`` becomes."""
    return [sys.executable, "-m", SERVICE_MODULE, *args]


def serve(ctx: typer.Context) -> None:
    """Run the Canal service here; every argument goes to ``python -m canal_service``
    (try ``canal serve --help``)."""
    if importlib.util.find_spec(SERVICE_MODULE) is None:
        error(f"canal serve runs the Canal service, but the {SERVICE_MODULE} package is not "
              f"installed in this Python ({sys.executable})")
        err.print(escape(f"hint: install it ({SERVICE_INSTALL}), or point --url (CANAL_URL) "
                         "at a running service"))
        raise typer.Exit(EXIT_REFUSED)
    cmd = service_command(list(ctx.args))
    sys.stdout.flush()
    sys.stderr.flush()
    if sys.platform == "win32":  # no exec there: wait for the service, pass on its exit code
        raise typer.Exit(subprocess.call(cmd))
    os.execv(cmd[0], cmd)
