"""``canal``: the command line of the Canal service (typer + rich), built on
:class:`canal_client.CanalClient`. ``canal --help`` lists the commands.

One module per command group: :mod:`.skills`, :mod:`.demos`, :mod:`.models` (fit, reproduce),
:mod:`.recordings` (export, view, recordings rebuild), :mod:`.simulation` (sim) and
:mod:`.serve`; :mod:`.root` puts them under one ``app``. Every expected error is one line on
stderr and an exit code: 1 refused by the service (4xx/5xx, or a bad file), 2 usage,
3 service unreachable.
"""

from __future__ import annotations

from .root import app, main

__all__ = ["app", "main"]
