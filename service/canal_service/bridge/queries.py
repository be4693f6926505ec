"""The per-stream queries a robot or a person sends over Zenoh, and what their bodies take.

One table says, for each query under ``{prefix}/{skill}/{robot}/``, the fields its JSON body
takes and the check each value must pass, so a body is refused in one place and in one way
(the field, what was expected, what came) before anything is captured.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from canal_core.options import CORRECTION_KINDS
from canal_protocol.options import MAX_CORRECTION_LABEL, MAX_CORRECTION_WEIGHT, MAX_DEMO_LABEL
from canal_protocol.schemas import shown_value


@dataclass(frozen=True)
class BodyField:
    """One field of a query body: the check its value passes, and how a refusal reads."""

    valid: Callable[[Any], bool]
    #: what the value must be, as the refusal says it ("expected {name} as {expected}")
    expected: str
    #: the reply's error type: ``invalid_input`` where REST refuses the same value of a
    #: correction, ``bad_payload`` for the capture's own bookkeeping
    error: str = "bad_payload"
    #: absent or null is refused; otherwise it means the default
    required: bool = False


def _seq_valid(value: Any) -> bool:
    return type(value) is int and 0 <= value < 2**64


def _text_within(limit: int) -> Callable[[Any], bool]:
    """A label's check: a text of at most ``limit`` characters, without NUL."""
    return lambda value: type(value) is str and len(value) <= limit and "\x00" not in value


def _weight_valid(value: Any) -> bool:
    """The bound a stored correction puts on an include's weight."""
    return type(value) in (int, float) and 0 < value <= MAX_CORRECTION_WEIGHT


_SEQ = BodyField(_seq_valid, "an integer in [0, 2**64)")
_DEMO_LABEL = BodyField(_text_within(MAX_DEMO_LABEL),
                        f"a text of at most {MAX_DEMO_LABEL} characters, without NUL")
# A correction's weight and label are checked at start, not at stop: a value the correction
# cannot keep must not cost the person the push.
_CORRECTION_LABEL = BodyField(_text_within(MAX_CORRECTION_LABEL),
                              f"a text of at most {MAX_CORRECTION_LABEL} characters, without NUL",
                              "invalid_input")
_WEIGHT = BodyField(_weight_valid, f"a number in (0, {MAX_CORRECTION_WEIGHT:g}]", "invalid_input")
_KIND = BodyField(lambda v: v in CORRECTION_KINDS, " or ".join(map(repr, CORRECTION_KINDS)),
                  "invalid_input", required=True)

#: The queries, as (chunk, chunk) after ``{prefix}/{skill}/{robot}/``, and the fields each
#: body takes, in the order a refusal names them.
STREAM_QUERIES: dict[tuple[str, str], dict[str, BodyField]] = {
    ("demo", "start"): {"from_seq": _SEQ, "label": _DEMO_LABEL},
    ("demo", "stop"): {"last_seq": _SEQ},
    ("correction", "start"): {"kind": _KIND, "weight": _WEIGHT, "label": _CORRECTION_LABEL,
                              "from_seq": _SEQ},
    ("correction", "stop"): {"last_seq": _SEQ},
    ("steer", "keep"): {"label": _CORRECTION_LABEL, "weight": _WEIGHT},
}


def body_error(body: dict[str, Any], query: tuple[str, str]) -> tuple[str, str, str] | None:
    """(error type, field, message) of the first field of ``query``'s body that the query
    does not take, is missing while required, or whose value fails its check; else None.

    A field the query does not take is refused, as over REST: a misspelt ``weight`` would
    otherwise leave the default in its place without a word.
    """
    fields = STREAM_QUERIES[query]
    for name in body:
        if name not in fields:
            return ("bad_payload", name,
                    f"expected only {', '.join(fields)}, got {shown_value(name)}")
    for name, field in fields.items():
        value = body.get(name)
        if (value is None and field.required) or (value is not None and not field.valid(value)):
            return field.error, name, f"expected {name} as {field.expected}, got {shown_value(value)}"
    return None


__all__ = ["STREAM_QUERIES", "BodyField", "body_error"]
