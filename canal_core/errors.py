"""The errors canal_core raises: one small hierarchy, documented once.

``CanalError``
    Base of everything canal_core raises on purpose. Catch this to catch them all.
``InvalidInputError(CanalError, ValueError)``
    An argument is malformed: wrong shape, NaN/Inf, too few points or demonstrations,
    timestamps that do not increase, an unknown option. ``field`` names the argument.
``DegenerateCanalError(CanalError)``
    The input is well formed but no canal can be built from it: every demonstration
    identical (zero radius everywhere), or a directrix of zero length.
``OutsideCanalError(CanalError)``
    A start point outside the canal when the caller asked for an error instead of a
    projection onto the boundary.
``ModelFormatError(CanalError, ValueError)``
    A serialised model that is not one this version can read.

The service maps these to HTTP once (422 for the first three, 400 for the last).
"""

from __future__ import annotations


class CanalError(Exception):
    """Base class of every error canal_core raises on purpose."""

    def __init__(self, message: str, *, field: str | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.field = field


class InvalidInputError(CanalError, ValueError):
    """An argument is malformed; ``field`` names it and the message says what was expected."""


class DegenerateCanalError(CanalError):
    """Well-formed input from which no canal can be built (e.g. all demonstrations identical)."""


class OutsideCanalError(CanalError):
    """A start point lies outside the canal and the caller asked for an error."""


class ModelFormatError(CanalError, ValueError):
    """A serialised model this version cannot read."""


class TooSlowError(CanalError):
    """A computation given a deadline (``time.monotonic()``) did not finish by it."""


__all__ = [
    "CanalError",
    "DegenerateCanalError",
    "InvalidInputError",
    "ModelFormatError",
    "OutsideCanalError",
    "TooSlowError",
]
