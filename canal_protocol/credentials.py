"""The live path's credentials when the service has a bearer token: one key for every door.

With ``--token``, the service closes its Zenoh endpoints with Zenoh's user/password
authentication: the user is :data:`LIVE_USER` and the password is derived from the token
(:func:`live_password`), so a robot that holds the token reaches the live path, and a
session without it is refused at connection (it can neither read a model, capture a demo,
nor get targets). The password is derived, not the token itself, so the users file handed to
Zenoh never holds the REST token.
"""

from __future__ import annotations

import hashlib
import hmac

import orjson

#: What a bearer token may hold: visible ASCII, no space (an HTTP header carries nothing else
#: intact: a space at either end is stripped, a control character or a letter outside ASCII
#: cannot be sent).
TOKEN_CHARACTERS = "visible ASCII characters without spaces or control characters"


def token_fault(token: str) -> str | None:
    """The first character of ``token`` a bearer token cannot hold, and where it is
    (``'é' at character 4 of 5``), or None. Never the whole token."""
    for i, c in enumerate(token, 1):
        if not "!" <= c <= "~":
            shown = "a space" if c == " " else repr(c)
            return f"{shown} at character {i} of {len(token)}"
    return None


def token_problem(token: str) -> str | None:
    """Why ``token`` cannot be a bearer token (the service's ``--token``, a client's), or None."""
    fault = token_fault(token)
    return None if fault is None else f"expected {TOKEN_CHARACTERS}, got {fault}"


#: The Zenoh user name of every session that holds the service's token.
LIVE_USER = "canal"
_LABEL = b"canal live path usrpwd v1"


def live_password(token: str) -> str:
    """The Zenoh password that goes with the bearer ``token``: HMAC-SHA256 keyed by the token
    over a fixed label, hex."""
    return hmac.new(token.encode(), _LABEL, hashlib.sha256).hexdigest()


def users_file_text(token: str) -> str:
    """The Zenoh users dictionary (``user:password`` lines) that admits the token's holder."""
    return f"{LIVE_USER}:{live_password(token)}\n"


def insert_credentials(config: object, token: str, users_file: str | None = None) -> None:
    """Make a ``zenoh.Config`` present the token's credentials when it connects and, with
    ``users_file`` (a file holding :func:`users_file_text`), admit only them when it is
    connected to."""
    insert = config.insert_json5  # type: ignore[attr-defined]
    insert("transport/auth/usrpwd/user", orjson.dumps(LIVE_USER).decode())
    insert("transport/auth/usrpwd/password", orjson.dumps(live_password(token)).decode())
    if users_file is not None:
        insert("transport/auth/usrpwd/dictionary_file", orjson.dumps(users_file).decode())


__all__ = ["LIVE_USER", "TOKEN_CHARACTERS", "insert_credentials", "live_password", "token_fault",
           "token_problem", "users_file_text"]
