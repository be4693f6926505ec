"""The magnitudes the canal computes with, and the checks that keep every input inside them.

Every number that enters a query of a fitted canal (a start, a goal, a duration, a time) is
checked here against a documented bound before any math runs, so an extreme value is refused
naming its field instead of overflowing into NaN, Inf or a crash deep inside the method.

The bounds, and why:

* **Coordinates**: ``|x| <= MAX_COORDINATE`` (1e15, the preparation stage's limit on
  demonstrations): squares and products of coordinates must stay far from float64 overflow.
  Obstacles' points and lengths (centre, ends, radius, half extents, clearance) too.
* **Angles**: a 2-D box's ``rotation`` (radians) within ``+-MAX_ANGLE`` (1e3, about 160
  turns): its sine and cosine keep ~1e-13 of absolute precision there; an angle of 1e16 or
  more has no fraction left and 1e300 is rounding, whatever box it stood for.
* **Reach**: a start or goal lies within ``MAX_REACH`` (1e6) canal sizes of the canal's
  centre, the size being the diagonal of the box around the directrix widened by its largest
  radius. Further out, the canal's own geometry vanishes in the rounding of the point's
  coordinates (a float64 keeps ~16 digits: at 1e6 sizes the canal still has ~1e-10 of its
  size of resolution), and the entry blend or goal deformation would stretch the canal
  beyond anything the frames can follow. A robot 1e6 canal sizes away from a 10 cm skill is
  100 km away.
* **Durations**: ``MIN_DURATION <= duration <= MAX_DURATION`` (1 ms to 1e6 s, ~11.6 days):
  shorter than one 1 kHz control tick cannot be executed and makes velocities overflow
  (1e-300 s made every velocity Inf); longer is no robot program, and its times would not fit
  a recording's nanosecond clock.
* **Times**: ``|t| <= MAX_TIME`` (1e11 s, ~3,000 years: epoch seconds fit, with ~1e-5 s of
  resolution left).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from .errors import InvalidInputError

FloatArray = npt.NDArray[np.float64]

#: Largest absolute coordinate of any point (demonstrations, starts, goals).
MAX_COORDINATE = 1e15
#: Largest absolute angle of a 2-D box's rotation, radians.
MAX_ANGLE = 1e3
#: Farthest a start or goal may be from the canal's centre, in canal sizes.
MAX_REACH = 1e6
#: Shortest reproduction duration, seconds (one tick of a 1 kHz controller).
MIN_DURATION = 1e-3
#: Longest reproduction duration, seconds (~11.6 days).
MAX_DURATION = 1e6
#: Largest absolute time stamp, seconds.
MAX_TIME = 1e11


def _first_over(values: FloatArray, limit: float) -> int | None:
    """Flat index of the first element with ``|v| > limit`` (or not finite), else None."""
    flat = np.asarray(values, dtype=np.float64).ravel()
    bad = ~(np.abs(flat) <= limit)  # NaN compares False: bad too
    if not bad.any():
        return None
    return int(np.argmax(bad))


def check_coordinates(values: Any, field: str, limit: float = MAX_COORDINATE) -> FloatArray:
    """Return ``values`` as a float array whose every element satisfies ``|v| <= limit``.

    Parameters
    ----------
    values : array_like, any shape
    field : str
        Name used in the error; a bad element of a (T, D) array is named ``field[row]``.
    limit : float
    """
    array = np.asarray(values, dtype=np.float64)
    at = _first_over(array, limit)
    if at is None:
        return array
    where = field if array.ndim < 2 else f"{field}[{at // array.shape[-1]}]"
    raise InvalidInputError(
        # the shortest exact form: a value just past the limit must not read as the limit
        f"expected {where} within +-{limit:g}, got {float(array.ravel()[at])!r}",
        field=where,
    )


#: The numbers of an obstacle (points and lengths, in the skill's units).
OBSTACLE_NUMBERS = ("center", "a", "b", "radius", "half_extents", "clearance")


def check_obstacle_numbers(obstacle: Any, field: str) -> None:
    """Refuse an obstacle (its JSON form) whose points or lengths exceed ``MAX_COORDINATE``,
    or whose 2-D rotation angle exceeds ``MAX_ANGLE``, naming ``field.key``; its shape and
    kind are :mod:`canal_core.obstacles`' to check (a 3-D rotation is a unit quaternion)."""
    if not isinstance(obstacle, dict):
        return
    angle = obstacle.get("rotation")
    if isinstance(angle, int | float) and not isinstance(angle, bool):
        check_coordinates(angle, f"{field}.rotation", MAX_ANGLE)
    for key in OBSTACLE_NUMBERS:
        value = obstacle.get(key)
        if value is not None:
            try:
                check_coordinates(value, f"{field}.{key}")
            except (TypeError, ValueError) as exc:
                if isinstance(exc, InvalidInputError):
                    raise
                return  # not numbers: obstacles.py says so with its own message


def canal_extent(directrix: FloatArray, radii: FloatArray) -> tuple[FloatArray, float]:
    """(centre (D,), size) of a canal: the box around its directrix widened by its largest
    radius; the size is the box's diagonal, never below the rounding of its coordinates.

    Parameters
    ----------
    directrix : array, shape (N, D)
    radii : array, shape (N,)
    """
    lo, hi = directrix.min(axis=0), directrix.max(axis=0)
    widen = float(np.max(radii)) if radii.size else 0.0
    centre = (lo + hi) / 2.0
    size = float(np.linalg.norm(hi - lo)) + 2.0 * widen
    return centre, max(size, 1e-12 * float(np.abs(directrix).max()), 1e-300)


def shown_past(value: float, *bounds: float) -> str:
    """``value`` to six significant digits, or to as many more as tell it from each of
    ``bounds``: a value just past a bound must not read as the bound in a refusal."""
    for digits in (6, 9, 12, 15):
        text = f"{value:.{digits}g}"
        if all(text != f"{b:.{digits}g}" for b in bounds):
            return text
    return repr(value)


def check_reach(point: Any, centre: FloatArray, size: float, field: str) -> FloatArray:
    """Return ``point`` (D,) once it is within ``MAX_REACH`` canal sizes of ``centre`` (and
    within ``MAX_COORDINATE``); otherwise an :class:`InvalidInputError` naming ``field``."""
    array = check_coordinates(point, field)
    distance = float(np.linalg.norm(array - centre))
    reach = MAX_REACH * size
    if not distance <= reach:
        raise InvalidInputError(
            f"expected {field} within {MAX_REACH:g} canal sizes ({reach:.6g}) of the canal's "
            f"centre, got a point {shown_past(distance, reach)} away: the canal cannot be computed with at "
            "that distance; check the units and frame of the point",
            field=field,
        )
    return array


def check_duration(value: Any, field: str = "duration") -> float:
    """Return ``value`` as seconds in [``MIN_DURATION``, ``MAX_DURATION``]."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise InvalidInputError(f"expected {field} as a number of seconds, got "
                                f"{type(value).__name__}", field=field)
    seconds = float(value)
    if not MIN_DURATION <= seconds <= MAX_DURATION:
        raise InvalidInputError(
            f"expected {field} between {MIN_DURATION:g} s and {MAX_DURATION:g} s, "
            f"got {shown_past(seconds, MIN_DURATION, MAX_DURATION)}",
            field=field,
        )
    return seconds


def check_times(values: Any, field: str = "timestamps") -> FloatArray:
    """Return ``values`` as a float array of seconds with every ``|t| <= MAX_TIME``."""
    array = np.asarray(values, dtype=np.float64)
    at = _first_over(array, MAX_TIME)
    if at is None:
        return array
    raise InvalidInputError(
        f"expected times within +-{MAX_TIME:g} s, got {shown_past(float(array.ravel()[at]), MAX_TIME, -MAX_TIME)} "
        f"at row {at}",
        field=f"{field}[{at}]",
    )


def first_non_finite(arrays: dict[str, Any]) -> str | None:
    """The name of the first of ``arrays`` (None values skipped) holding NaN or Inf, else None.

    The last guard before an answer leaves: a number that is not finite must never be sent
    (JSON has no Inf; it would become ``null``).
    """
    for name, value in arrays.items():
        if value is None:
            continue
        if not np.isfinite(np.asarray(value, dtype=np.float64)).all():
            return name
    return None
