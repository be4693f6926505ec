"""Validators in one place: each says what it expected and what it got.

Every public entry point of canal_core passes its arguments through these ``check_*``
functions before doing any math, so a malformed call fails early with an
:class:`~canal_core.errors.InvalidInputError` whose ``field`` names the argument.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from .bounds import shown_past
from .errors import InvalidInputError

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

MIN_POINTS = 4
MIN_DEMOS = 2
DIMENSIONS = (2, 3)


def _as_float_array(value: Any, field: str) -> FloatArray:
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        # Only a failure pays for the walk; numpy's own text ("inhomogeneous shape after 1
        # dimensions") names neither the row nor what was wrong with it.
        named = malformed_entry(value, field)
        if named is not None:
            raise named from exc
        raise InvalidInputError(
            f"expected {field} as an array of numbers, got {type(value).__name__} ({exc})",
            field=field,
        ) from exc
    return array


def _kind(value: Any) -> str:
    """What came, in the words of the JSON it most likely came from."""
    if value is None:
        return "null"
    if isinstance(value, str | bytes):
        return f"text {value!r:.24}"
    if isinstance(value, dict):
        return "an object"
    return type(value).__name__


def _is_row(value: Any) -> bool:
    return isinstance(value, Sequence | np.ndarray) and not isinstance(value, str | bytes)


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float | np.number)


def malformed_entry(value: Any, field: str, width: int | None = None, what: str = "") -> InvalidInputError | None:
    """The first entry of a list of numbers, or of rows of numbers, that cannot be read as
    one array, named by index (``field[i]`` or ``field[i][j]``); None when there is none or
    ``value`` is not a list.

    Parameters
    ----------
    value : list of numbers, or list of rows of numbers
    field : str
        Name used in the error.
    width : int, optional
        The values every row must have (rows are expected then); as the first row has when None.
    what : str
        What a row's values are, for the message ("x, y, z for a 3-D skill").
    """
    if not _is_row(value) or len(value) == 0:
        return None
    if width is None and not _is_row(value[0]):
        for i, x in enumerate(value):
            if not _is_number(x):
                return InvalidInputError(f"expected a number at {field}[{i}], got {_kind(x)}",
                                         field=f"{field}[{i}]")
        return None
    width = len(value[0]) if width is None else width
    said = f"({what})" if what else "(as row 0 has)"
    for i, row in enumerate(value):
        if not _is_row(row):
            return InvalidInputError(f"expected {field}[{i}] as a row of {width} numbers, got {_kind(row)}",
                                     field=f"{field}[{i}]")
        if len(row) != width:
            return InvalidInputError(
                f"expected {width} values per row of {field} {said}, got {len(row)} values at row {i}",
                field=f"{field}[{i}]",
            )
        for j, x in enumerate(row):
            if not _is_number(x):
                return InvalidInputError(f"expected a number at {field}[{i}][{j}], got {_kind(x)}",
                                         field=f"{field}[{i}][{j}]")
    return None


def check_finite(array: FloatArray, field: str) -> None:
    """Raise if ``array`` holds NaN or Inf, naming the first bad row."""
    bad = ~np.isfinite(array)
    if bad.any():
        row = int(np.argwhere(bad)[0][0])
        raise InvalidInputError(
            f"expected finite {field}, got NaN or Inf at row {row}", field=field
        )


def check_positions(value: Any, field: str = "positions", dim: int | None = None) -> FloatArray:
    """Return ``value`` as a finite float array of shape (T, D), T >= 4, D in {2, 3}.

    Parameters
    ----------
    value : array_like, shape (T, D)
    field : str
        Name used in error messages.
    dim : int, optional
        Required dimension D; any of 2 or 3 when None.
    """
    array = _as_float_array(value, field)
    expected_dim = "D" if dim is None else str(dim)
    if array.ndim != 2 or array.shape[1] not in DIMENSIONS or (
        dim is not None and array.shape[1] != dim
    ):
        within = " with D in {2, 3}" if dim is None else ""
        raise InvalidInputError(
            f"expected {field} of shape (T, {expected_dim}){within}, got {array.shape}",
            field=field,
        )
    if array.shape[0] < MIN_POINTS:
        raise InvalidInputError(
            f"expected at least {MIN_POINTS} points in {field}, got {array.shape[0]}",
            field=field,
        )
    check_finite(array, field)
    return array


def check_timestamps(value: Any, n_points: int, field: str = "timestamps") -> FloatArray:
    """Return ``value`` as a finite float array of shape (T,).

    Their order is checked (and equal or isolated out-of-order stamps repaired) by
    :func:`canal_core.preprocess.prepared_demonstration`, which names the sample at fault.
    """
    array = _as_float_array(value, field)
    if array.ndim != 1 or array.shape[0] != n_points:
        raise InvalidInputError(
            f"expected {field} of shape ({n_points},), got {array.shape}", field=field
        )
    check_finite(array, field)
    return array


def check_demonstrations(
    demos: Any, timestamps: Any = None, at_least: int = MIN_DEMOS
) -> tuple[list[FloatArray], list[FloatArray | None], int]:
    """Validate a set of demonstrations and their optional timestamps.

    Parameters
    ----------
    demos : sequence of array_like, each shape (T_j, D)
        At least ``at_least`` demonstrations (two for a canal) of one dimension D in {2, 3},
        each with T_j >= 4.
    timestamps : sequence of (array_like, shape (T_j,) or None), optional
    at_least : int

    Returns
    -------
    demos : list of arrays, each shape (T_j, D)
    timestamps : list of (array, shape (T_j,)) or None
    dim : int
    """
    if isinstance(demos, np.ndarray) and demos.ndim == 3:
        demos = list(demos)
    if not isinstance(demos, Sequence) or isinstance(demos, str | bytes):
        raise InvalidInputError(
            f"expected demos as a list of (T_j, D) arrays, got {type(demos).__name__}",
            field="demos",
        )
    if len(demos) < at_least:
        raise InvalidInputError(
            f"expected at least {at_least} demonstrations in demos, got {len(demos)}", field="demos"
        )
    checked = [check_positions(d, f"demos[{j}]") for j, d in enumerate(demos)]
    dims = {d.shape[1] for d in checked}
    if len(dims) != 1:
        shapes = [d.shape for d in checked]
        raise InvalidInputError(
            f"expected every demonstration in demos to have the same dimension D, got shapes {shapes}",
            field="demos",
        )
    if timestamps is None:
        times: list[FloatArray | None] = [None] * len(checked)
    else:
        if not isinstance(timestamps, Sequence) or len(timestamps) != len(checked):
            got = len(timestamps) if isinstance(timestamps, Sequence) else type(timestamps).__name__
            raise InvalidInputError(
                f"expected timestamps as a list of {len(checked)} arrays (one per demo), got {got}",
                field="timestamps",
            )
        times = [
            None if t is None else check_timestamps(t, d.shape[0], f"timestamps[{j}]")
            for j, (d, t) in enumerate(zip(checked, timestamps, strict=True))
        ]
    return checked, times, dims.pop()


def check_point(value: Any, dim: int, field: str = "start") -> FloatArray:
    """Return ``value`` as a finite float array of shape (D,)."""
    array = _as_float_array(value, field)
    if array.shape != (dim,):
        raise InvalidInputError(f"expected {field} of shape ({dim},), got {array.shape}", field=field)
    check_finite(array, field)
    return array


def check_points(value: Any, dim: int, field: str = "points") -> FloatArray:
    """Return ``value`` as a finite float array of shape (M, D); a single (D,) point becomes (1, D)."""
    array = _as_float_array(value, field)
    if array.ndim == 1 and array.shape == (dim,):
        array = array[None, :]
    if array.ndim != 2 or array.shape[1] != dim:
        raise InvalidInputError(
            f"expected {field} of shape (M, {dim}), got {array.shape}", field=field
        )
    check_finite(array, field)
    return array


def check_choice(value: Any, allowed: Sequence[str], field: str) -> str:
    """Return ``value`` if it is one of ``allowed``."""
    if value not in allowed:
        raise InvalidInputError(
            f"expected {field} to be one of {', '.join(map(repr, allowed))}, got {value!r}",
            field=field,
        )
    return str(value)


def check_int(value: Any, minimum: int, field: str, maximum: int | None = None) -> int:
    """Return ``value`` as an int in [minimum, maximum]."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise InvalidInputError(
            f"expected {field} as an integer, got {type(value).__name__}", field=field
        )
    if value < minimum or (maximum is not None and value > maximum):
        upper = "" if maximum is None else f" and <= {maximum}"
        raise InvalidInputError(f"expected {field} >= {minimum}{upper}, got {value}", field=field)
    return int(value)


def check_positive(value: Any, field: str) -> float:
    """Return ``value`` as a finite float > 0."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise InvalidInputError(f"expected {field} as a number, got {type(value).__name__}", field=field)
    if not np.isfinite(value) or value <= 0.0:
        raise InvalidInputError(f"expected {field} as a finite number > 0, got {value}", field=field)
    return float(value)


def check_fraction(value: Any, field: str, maximum: float = 0.25) -> float:
    """Return ``value`` as a finite float in [0, maximum]."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise InvalidInputError(f"expected {field} as a number, got {type(value).__name__}", field=field)
    if not np.isfinite(value) or value < 0.0 or value > maximum:
        raise InvalidInputError(f"expected {field} in [0, {maximum}], got {value}", field=field)
    return float(value)


#: Largest | |q| - 1 | accepted for a unit quaternion before it is renormalised. Robot
#: drivers often send float32 quaternions, renormalised loosely; 1e-3 accepts those and still
#: catches Euler angles, rotation vectors or unnormalised garbage.
QUATERNION_NORM_TOLERANCE = 1e-3
#: the norms a quaternion may have, shown apart from a norm just past them
_NORM_BOUNDS = (1.0 - QUATERNION_NORM_TOLERANCE, 1.0 + QUATERNION_NORM_TOLERANCE)


def check_quaternions(
    value: Any, n_rows: int | None = None, field: str = "orientations"
) -> FloatArray:
    """Return ``value`` as finite unit quaternions [qx, qy, qz, qw] of shape (T, 4), normalised.

    Parameters
    ----------
    value : array_like, shape (T, 4)
    n_rows : int, optional
        Required T (one orientation per position).
    field : str
        Name used in error messages; a bad row is named ``field[i]``.
    """
    array = _as_float_array(value, field)
    rows = "T" if n_rows is None else str(n_rows)
    if array.ndim != 2 or array.shape[1] != 4 or (n_rows is not None and array.shape[0] != n_rows):
        raise InvalidInputError(
            f"expected {field} of shape ({rows}, 4) as qx, qy, qz, qw rows, got {array.shape}",
            field=field,
        )
    check_finite(array, field)
    with np.errstate(over="ignore"):  # a norm beyond float64 is Inf, refused below
        norms = np.linalg.norm(array, axis=1)
    bad = np.abs(norms - 1.0) > QUATERNION_NORM_TOLERANCE
    if bad.any():
        i = int(np.argmax(bad))
        raise InvalidInputError(
            f"expected unit quaternions in {field} (norm 1 +- {QUATERNION_NORM_TOLERANCE}), "
            f"got norm {shown_past(float(norms[i]), *_NORM_BOUNDS)} at row {i}",
            field=f"{field}[{i}]",
        )
    return np.asarray(array / norms[:, None])


def check_quaternion(value: Any, field: str = "start_orientation") -> FloatArray:
    """Return ``value`` as one finite unit quaternion [qx, qy, qz, qw], shape (4,), normalised."""
    array = _as_float_array(value, field)
    if array.shape != (4,):
        raise InvalidInputError(
            f"expected {field} of shape (4,) as qx, qy, qz, qw, got {array.shape}", field=field
        )
    check_finite(array[None, :], field)
    with np.errstate(over="ignore"):  # a norm beyond float64 is Inf, refused below
        norm = float(np.linalg.norm(array))
    if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
        raise InvalidInputError(
            f"expected {field} as a unit quaternion (norm 1 +- {QUATERNION_NORM_TOLERANCE}), "
            f"got norm {shown_past(norm, *_NORM_BOUNDS)}",
            field=field,
        )
    return np.asarray(array / norm)


def check_demonstration_orientations(orientations: Any, demos: list[FloatArray]) -> list[FloatArray]:
    """Validate one (T_j, 4) quaternion array per demonstration; each comes back normalised.

    Parameters
    ----------
    orientations : sequence of array_like, each shape (T_j, 4)
        Unit quaternions [qx, qy, qz, qw], one per position of ``demos[j]``.
    demos : list of arrays, each shape (T_j, D)
        The checked demonstrations.
    """
    if isinstance(orientations, np.ndarray) and orientations.ndim == 3:
        orientations = list(orientations)
    if not isinstance(orientations, Sequence) or isinstance(orientations, str | bytes) or len(
        orientations
    ) != len(demos):
        got = len(orientations) if isinstance(orientations, Sequence) else type(orientations).__name__
        raise InvalidInputError(
            f"expected orientations as a list of {len(demos)} (T_j, 4) arrays (one per demo), got {got}",
            field="orientations",
        )
    return [
        check_quaternions(q, d.shape[0], f"orientations[{j}]")
        for j, (q, d) in enumerate(zip(orientations, demos, strict=True))
    ]
