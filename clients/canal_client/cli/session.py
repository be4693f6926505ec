"""The global options (``--url``, ``--token``, ``--json``) and the client a command talks
through, which turns every expected client error into a message and an exit code."""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Iterator
from typing import Annotated, Any

import httpx
import typer

from canal_protocol.credentials import TOKEN_CHARACTERS, token_problem

from ..errors import ApiError, CanalClientError, ConnectionFailedError, RequestTimeoutError
from ..rest import DEFAULT_URL, CanalClient
from .output import EXIT_REFUSED, EXIT_UNREACHABLE, err, error


@dataclasses.dataclass(frozen=True)
class Options:
    """Global options, shared by every command through the click context."""

    url: str = DEFAULT_URL
    token: str | None = None
    json: bool = False


def global_options(
    ctx: typer.Context,
    url: Annotated[str, typer.Option("--url", envvar="CANAL_URL",
                                     help="Base URL of the Canal service.")] = DEFAULT_URL,
    token: Annotated[str | None, typer.Option(
        "--token", envvar="CANAL_TOKEN",
        help=f"Bearer token, when the service needs one ({TOKEN_CHARACTERS}).")] = None,
    json_output: Annotated[bool, typer.Option("--json",
                                              help="Machine-readable JSON on stdout.")] = False,
) -> None:
    """The root command's callback: keeps the global options for the command that follows."""
    ctx.obj = Options(url=service_url(url), token=bearer_token(token), json=json_output)


def bearer_token(text: str | None) -> str | None:
    """``--token`` as sent, None when empty; one no HTTP header can carry (a letter outside
    ASCII, a space, a newline) is a usage error saying which character came, never the token."""
    if not text:
        return None
    problem = token_problem(text)
    if problem is not None:
        raise typer.BadParameter(problem, param_hint="--token (or CANAL_TOKEN)")
    return text


def service_url(text: str) -> str:
    """``--url`` as a base URL: ``host:port`` (as curl takes it) is ``http://host:port``. One
    that names no host (empty, ``http://``), or that cannot be parsed (``http://[::1``, a port
    that is not one) is a usage error saying what came."""
    text = text.strip()
    scheme, sep, _ = text.partition("://")
    url = text if sep else f"http://{text}"
    expected = f"expected an http:// or https:// URL like {DEFAULT_URL}"
    if sep and scheme.lower() not in ("http", "https"):
        raise typer.BadParameter(f"{expected}, got {text!r}", param_hint="--url (or CANAL_URL)")
    try:
        parsed = httpx.URL(url)
        ok = bool(parsed.host) and (parsed.port is None or 0 < parsed.port < 65536)
    except httpx.InvalidURL:
        ok = False
    if not ok:
        raise typer.BadParameter(f"{expected} (a host, and a port from 1 to 65535 if any), "
                                 f"got {text!r}", param_hint="--url (or CANAL_URL)")
    return url


def options(ctx: typer.Context) -> Options:
    """The global options of this invocation."""
    obj = ctx.find_root().obj
    return obj if isinstance(obj, Options) else Options()


def fail_unreachable(exc: CanalClientError, url: str) -> typer.Exit:
    """Print why the service could not be reached (and how to start one); exit code 3."""
    error(str(exc))
    if isinstance(exc, ConnectionFailedError):
        err.print("hint: start the service with 'canal serve', or point --url (CANAL_URL) "
                  "at a running one")
    return typer.Exit(EXIT_UNREACHABLE)


@contextlib.contextmanager
def connected(ctx: typer.Context) -> Iterator[CanalClient]:
    """A client for the command; every expected error becomes a message and an exit code."""
    opts = options(ctx)
    client = CanalClient(opts.url, token=opts.token, timeout=300.0)
    try:
        yield client
    except ApiError as exc:
        error(str(exc))
        raise typer.Exit(EXIT_REFUSED) from None
    except (ConnectionFailedError, RequestTimeoutError) as exc:
        raise fail_unreachable(exc, opts.url) from None
    except CanalClientError as exc:
        error(str(exc))
        raise typer.Exit(EXIT_REFUSED) from None
    finally:
        client.close()


def health_document(opts: Options) -> dict[str, Any]:
    """The service's /healthz document (also when it says 503 degraded: it still knows its
    bridge and its recorder)."""
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
