"""The service's command line, generated from :class:`~canal_service.core.config.Settings`:
one flag per setting, each also a ``CANAL_*`` variable (``python -m canal_service`` and
``python -m canal_service.bridge`` parse with it; ``canal serve`` passes its arguments on)."""

from __future__ import annotations

import argparse
import json
import logging
import logging.handlers
import typing
from collections.abc import Awaitable, Callable, MutableMapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

from pydantic import SecretStr, ValidationError
from pydantic.fields import FieldInfo
from pydantic_core import PydanticUndefined

from .config import Flag, Settings

if TYPE_CHECKING:  # both take seconds to import; the port is bound before they load
    pass

log = logging.getLogger("uvicorn.error")  # configured by uvicorn: our lines beside its own
READY_WAIT_S = 300.0

Scope = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[MutableMapping[str, Any]]]
Send = Callable[[MutableMapping[str, Any]], Awaitable[None]]

#: What ``python -m canal_service --help`` says first.
DESCRIPTION = """``python -m canal_service``: serve the API with uvicorn.

Flags override ``CANAL_*`` environment variables, which override the embedded defaults
(127.0.0.1:8000, SQLite and recordings under ./data).

The port is bound and ``/healthz`` answers at once (503 ``{"status": "starting"}``) while the
application loads behind it: the scientific stack, migrations, the recorder and the Zenoh
bridge take seconds; then ``/healthz`` says ``ok`` and every route is served. Requests that
arrive meanwhile wait for it. One log line says where REST and Zenoh listen.
"""

# Settings whose names start with these are listed under a heading of their own in --help.
_GROUPS = {"recordings_": "recordings", "upload_": "upload limits",
           "zenoh_": "live bridge (Zenoh)"}


@dataclass(frozen=True)
class Option:
    """One command-line flag, derived from one ``Settings`` field."""

    field: str
    flag: str
    kind: Literal["value", "list", "switch"]
    help: str
    metavar: str | None
    const: bool | None = None  # what a switch sets


def _default_text(info: FieldInfo) -> str | None:
    if info.default_factory is not None:
        value = info.get_default(call_default_factory=True)
        return json.dumps(value) if value else None
    value = info.default
    if value is None or value is PydanticUndefined or isinstance(value, SecretStr):
        return None
    return str(value)


def settings_options(model: type[Settings] = Settings) -> list[Option]:
    """One flag per field of ``model`` (``Settings``), in the model's order.

    ``--field-name`` unless a :class:`Flag` in the field's annotation spells it; a bool is a
    switch setting the opposite of its default; a list is repeated once per item. The help
    is the field's description, its ``CANAL_*`` variable and its default.
    """
    options = []
    for name, info in model.model_fields.items():
        spelling = next((m for m in info.metadata if isinstance(m, Flag)), Flag())
        flag = spelling.name or "--" + name.replace("_", "-")
        env = f"CANAL_{name.upper()}"
        description = (info.description or name.replace("_", " ")).rstrip(".")
        if info.annotation is bool:
            const = not info.default
            state = "on" if const else "off"
            options.append(Option(name, flag, "switch", f"{description} (this flag turns it "
                                   f"{state}: {env}={str(const).lower()})", None, const))
            continue
        origin = typing.get_origin(info.annotation)
        kind: Literal["value", "list"] = "list" if origin is list else "value"
        extra = [env + (" as a JSON list or items apart by commas; the flag is repeatable"
                       if kind == "list" else "")]
        default = _default_text(info)
        if default is not None:
            extra.append(f"default {default}")
        options.append(Option(name, flag, kind, f"{description} ({', '.join(extra)})",
                               spelling.metavar))
    return options


def build_parser(model: type[Settings] = Settings) -> argparse.ArgumentParser:
    """The command line, generated from ``model`` (``Settings``): every flag is also a CANAL_*
    variable."""
    p = argparse.ArgumentParser(prog="python -m canal_service", description=DESCRIPTION,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    # Each flag is added by the parser's or its heading's group's add_argument.
    adders: dict[str, Callable[..., argparse.Action]] = {}
    for option in settings_options(model):
        heading = next((h for prefix, h in _GROUPS.items() if option.field.startswith(prefix)),
                       None)
        add: Callable[..., argparse.Action] = p.add_argument
        if heading is not None:
            if heading not in adders:
                adders[heading] = p.add_argument_group(heading).add_argument
            add = adders[heading]
        # Defaults stay None: only flags given on the command line override the environment.
        if option.kind == "switch":
            add(option.flag, dest=option.field, action="store_const",
                const=option.const, default=None, help=option.help)
        else:
            add(option.flag, dest=option.field, default=None,
                action="append" if option.kind == "list" else "store",
                metavar=option.metavar, help=option.help)
    return p


def settings_from_args(argv: Sequence[str] | None = None,
                       model: type[Settings] = Settings) -> Settings:
    """Settings from the environment, with the given flags on top.

    A value that does not validate exits with a usage error naming its flag (status 2).
    """
    parser = build_parser(model)
    args = parser.parse_args(argv)
    overrides: dict[str, Any] = {k: v for k, v in vars(args).items() if v is not None}
    try:
        return model(**overrides)
    except ValidationError as exc:
        flags = {o.field: o.flag for o in settings_options(model)}
        problems = []
        for error in exc.errors(include_url=False):
            field = str(error["loc"][0]) if error["loc"] else ""
            where = (f"{flags[field]} (or CANAL_{field.upper()})" if field in flags
                     else field or "settings")
            got = error.get("input")
            # a message that says what came already (a token's: never the secret itself)
            said = ", got " in error["msg"]
            came = "" if isinstance(got, dict) or got is None or said else f", got {got!r}"
            problems.append(f"{where}: {error['msg']}{came}")
        parser.error("; ".join(problems))


def endpoints_line(settings: Settings) -> str:
    """One line: where REST and Zenoh listen."""
    host = f"[{settings.host}]" if ":" in settings.host else settings.host
    rest = f"REST http://{host}:{settings.port}"
    if not settings.zenoh_enabled:
        zenoh = "Zenoh off (--no-zenoh)"
    elif settings.zenoh_config is not None:
        zenoh = f"Zenoh as configured in {settings.zenoh_config} (prefix {settings.zenoh_prefix})"
    else:
        where = ", ".join(settings.zenoh_listen) or "no listen endpoint"
        if settings.zenoh_connect:
            where += f"; connects to {', '.join(settings.zenoh_connect)}"
        zenoh = f"Zenoh {where} (prefix {settings.zenoh_prefix})"
    if settings.token is not None and settings.zenoh_enabled:
        zenoh += ", live path OPEN to anyone (--zenoh-open)" if settings.zenoh_open else \
            ", live path closed by the token"
    return f"canal service: {rest}, {zenoh}"
