"""Checks on a demonstration before anything is stored.

Pure functions: arrays in, checked arrays out, or an :class:`InvalidInput` naming the field,
the row and what was expected. Every source (JSON, CSV, NPY, MCAP) ends here, so the rules
are the same whichever way a demonstration arrives.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from canal_core import bounds
from canal_core.errors import CanalError
from canal_core.preprocess import prepared_demonstration
from canal_core.validation import check_quaternion, check_quaternions, malformed_entry
from canal_protocol.options import TIME_UNITS

from .errors import InvalidInput

FloatArray = npt.NDArray[np.float64]

MIN_POINTS = 4
#: Longest demonstration, in seconds: a longer span is almost always stamps in ms, us or ns
#: read as seconds (a ROS log's nanoseconds made a 10 s demo last 317 years)
MAX_DEMO_SECONDS = 3600.0
#: Shortest demonstration, in seconds: one tick of a 1 kHz controller, the shortest
#: reproduction ``duration`` (:data:`canal_core.bounds.MIN_DURATION`). A demonstration
#: stamped shorter is reproduced as fast: 1e-12 s made velocities of 1e7 m/s.
MIN_DEMO_SECONDS = bounds.MIN_DURATION


@dataclass(frozen=True)
class DemoArrays:
    """A checked demonstration: positions (T, D), optional timestamps (T,) and quaternions (T, 4)."""

    positions: FloatArray
    timestamps: FloatArray | None = None
    orientations: FloatArray | None = None

    @property
    def n_points(self) -> int:
        """Number of samples T."""
        return int(self.positions.shape[0])


def _matrix(value: Any, field: str, columns: int, what: str) -> FloatArray:
    """``value`` as a (T, columns) float array; ragged rows and wrong widths named by row."""
    if isinstance(value, np.ndarray):
        array = value
    else:
        # Fast path: a well-formed list converts in one call; only a failure pays for the
        # row-by-row walk that names the bad row.
        fast: FloatArray | None
        try:
            fast = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            fast = None
        if fast is not None and fast.ndim == 2 and fast.shape[1] == columns:
            return np.ascontiguousarray(fast)
        if not isinstance(value, Sequence) or isinstance(value, str | bytes):
            raise InvalidInput(f"expected {field} as a list of rows, got {type(value).__name__}",
                               field=field)
        named = malformed_entry(value, field, columns, what)
        if named is not None:
            raise InvalidInput(named.message, field=named.field)
        try:
            array = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise InvalidInput(f"expected numbers in {field}: {exc}", field=field) from exc
    if array.ndim != 2 or array.shape[1] != columns:
        raise InvalidInput(
            f"expected {field} of shape (T, {columns}) ({what}), got {tuple(array.shape)}",
            field=field,
        )
    return np.ascontiguousarray(array, dtype=np.float64)


def _check_finite(array: FloatArray, field: str) -> None:
    bad = ~np.isfinite(array)
    if bad.any():
        row = int(np.argwhere(bad)[0][0])
        raise InvalidInput(f"expected finite numbers, got NaN or Inf at row {row}",
                           field=f"{field}[{row}]")


def check_positions(value: Any, dim: int, field: str = "positions") -> FloatArray:
    """Positions as a finite (T, dim) array with T >= 4; a bad one named ``field``
    (``positions`` of a demonstration, ``samples`` of a correction's path)."""
    axes = "x, y" if dim == 2 else "x, y, z"
    positions = _matrix(value, field, dim, f"{axes} for a {dim}-D skill")
    if positions.shape[0] < MIN_POINTS:
        raise InvalidInput(
            f"expected at least {MIN_POINTS} points, got {positions.shape[0]}", field=field
        )
    _check_finite(positions, field)
    return positions


def check_timestamps(value: Any, n_points: int, unit: str | None = None,
                     min_span: float = MIN_DEMO_SECONDS) -> FloatArray:
    """Timestamps as a finite (T,) array of seconds, spanning at most ``MAX_DEMO_SECONDS``
    and, when they advance at all, at least ``min_span`` (a demonstration's
    ``MIN_DEMO_SECONDS``; stamps that never advance are the fit's rule's to refuse).

    With ``unit`` (a key of :data:`TIME_UNITS`) other than seconds they are converted to
    seconds from the first sample (subtracting first keeps epoch nanoseconds exact to the
    float's resolution); otherwise they are kept as sent. Their order is not checked here
    but by :func:`check_fittable`, with the fit's own rule: a raw log's equal stamps (a
    polling logger, a coarse clock) and isolated late or early samples are accepted and
    repaired when the canal is fitted; time going back for more than one sample (a clock
    reset, logs joined together) is refused.
    """
    try:
        times = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"expected timestamps as a list of numbers: {exc}",
                           field="timestamps") from exc
    if times.ndim != 1:
        raise InvalidInput(f"expected timestamps as a flat list, got shape {times.shape}",
                           field="timestamps")
    if times.shape[0] != n_points:
        raise InvalidInput(
            f"expected one timestamp per position ({n_points}), got {times.shape[0]}",
            field="timestamps",
        )
    _check_finite(times[:, None], "timestamps")
    # Stamps near the float limits overflow to an infinite span, which the check below refuses.
    with np.errstate(over="ignore"):
        if unit is not None and unit != "s" and times.size:
            times = (times - times[0]) * TIME_UNITS[unit]
        span = float(times.max() - times.min()) if times.size else 0.0
    if span > MAX_DEMO_SECONDS:
        raise InvalidInput(
            f"expected timestamps in seconds spanning at most {MAX_DEMO_SECONDS:g} s (one "
            f"hour), got a span of {span:.3g} s: are they milliseconds, microseconds or "
            f"nanoseconds? An upload says so with ?time_unit=ms, us or ns (a live pose's t "
            f"is in seconds)",
            field="timestamps",
        )
    if 0.0 < span < min_span:
        raise InvalidInput(
            f"expected timestamps in seconds spanning at least {min_span:g} s (one tick of a "
            f"1 kHz controller, the shortest reproduction), got a span of {span:.3g} s: are "
            f"they in seconds? An upload says which unit they are in with ?time_unit=s, ms, us "
            f"or ns (a live capture's span is that of its poses' t, in seconds)",
            field="timestamps",
        )
    _core_checked(bounds.check_times, times, "timestamps")
    return times


def check_orientations(value: Any, n_points: int) -> FloatArray:
    """Orientations as (T, 4) unit quaternions in (qx, qy, qz, qw) order."""
    quats = _matrix(value, "orientations", 4, "qx, qy, qz, qw")
    if quats.shape[0] != n_points:
        raise InvalidInput(
            f"expected one orientation per position ({n_points}), got {quats.shape[0]}",
            field="orientations",
        )
    _check_finite(quats, "orientations")
    try:  # the unit-norm rule (and its tolerance) is canal_core's, the one fit applies
        check_quaternions(quats, n_points, "orientations")
    except CanalError as exc:
        raise InvalidInput(exc.message, field=exc.field) from exc
    return quats  # stored as sent; fit normalises


def check_fittable(positions: FloatArray, timestamps: FloatArray | None) -> None:
    """Run canal_core's preparation stage, as ``fit`` will, so an unfittable demo is refused now.

    Once, the way ``fit`` prepares this demo: with its timestamps when it has them (``fit``
    prepares stamped demos with their timestamps whatever the alignment, since the stamps
    give the speed profile), by arc length otherwise. canal_core names the demo
    ``positions`` / ``timestamps`` here.
    """
    try:
        prepared_demonstration(positions, timestamps, field="positions", time_field="timestamps")
    except CanalError as exc:
        raise InvalidInput(f"demonstration cannot be fitted: {exc.message}",
                           field=exc.field or "positions") from exc


def check_demonstration(
    positions: Any, dim: int, timestamps: Any = None, orientations: Any = None,
    time_unit: str | None = None, fittable: bool = True,
) -> DemoArrays:
    """Run every check; the first failure raises :class:`InvalidInput`.

    After the per-field checks, the demo goes through canal_core's preparation stage
    (:func:`check_fittable`): identical points, coordinates beyond +-1e15 or a demo that
    only stands still are refused here with a 422, never found out at fit time. A
    correction's path (``fittable=False``) is not fitted: its own checks say what it needs,
    and its rows are named ``samples``, as in a JSON correction.
    ``time_unit`` is the unit of ``timestamps`` (:func:`check_timestamps`; None: seconds).
    """
    checked = check_positions(positions, dim, "positions" if fittable else "samples")
    n = checked.shape[0]
    if timestamps is None and time_unit is not None:
        raise InvalidInput(f"time_unit={time_unit} was given, but the demonstration has no "
                           "timestamps (no time column)", field="time_unit")
    # a correction's path is held to the rules a JSON correction is (canal_core.corrections)
    times = None if timestamps is None else check_timestamps(
        timestamps, n, time_unit, MIN_DEMO_SECONDS if fittable else 0.0)
    quats = None if orientations is None else check_orientations(orientations, n)
    if fittable:
        check_fittable(checked, times)
    return DemoArrays(checked, times, quats)


def _core_checked(check: Any, value: Any, field: str) -> Any:
    """``check(value, field)`` from :mod:`canal_core.bounds`, its refusal as :class:`InvalidInput`."""
    try:
        return check(value, field)
    except CanalError as exc:
        raise InvalidInput(exc.message, field=exc.field or field) from exc


@dataclass(frozen=True)
class ReproductionInputs:
    """A reproduction request's numbers, checked against the canal (:mod:`canal_core.bounds`)."""

    starts: list[FloatArray]
    goal: FloatArray | None
    duration: float | None
    start_orientation: FloatArray | None = None


def check_reproduction_inputs(
    directrix: FloatArray, radii: FloatArray, starts: Sequence[Any], fields: Sequence[str],
    goal: Any, duration: Any, start_orientation: Any = None,
) -> ReproductionInputs:
    """Every number of a reproduction request, checked in one place before any is computed.

    Starts and the goal must have the canal's dimension and lie within
    :data:`canal_core.bounds.MAX_REACH` canal sizes of its centre; the duration must be
    within [:data:`~canal_core.bounds.MIN_DURATION`, :data:`~canal_core.bounds.MAX_DURATION`];
    a start orientation must be a unit quaternion, also where the model has no orientation to
    use it on (a value that is no rotation is a client's bug either way).
    """
    dim = directrix.shape[1]
    centre, size = bounds.canal_extent(directrix, radii)

    def point(value: Any, field: str) -> FloatArray:
        if len(value) != dim:
            raise InvalidInput(f"expected {dim} coordinates for a {dim}-D skill, got {len(value)}",
                               field=field)
        return _core_checked(lambda v, f: bounds.check_reach(v, centre, size, f), value, field)

    checked = [point(start, field) for start, field in zip(starts, fields, strict=True)]
    goal_ = None if goal is None else point(goal, "goal")
    duration_ = None if duration is None else _core_checked(bounds.check_duration, duration,
                                                           "duration")
    orientation = None if start_orientation is None else _core_checked(check_quaternion, start_orientation,
                                                                        "start_orientation")
    return ReproductionInputs(checked, goal_, duration_, orientation)


def check_finite_answer(arrays: dict[str, Any], inputs: str) -> None:
    """The last guard: refuse (422) an answer holding NaN or Inf, which JSON would send as null.

    ``inputs`` names the request fields the answer was computed from.
    """
    bad = bounds.first_non_finite(arrays)
    if bad is not None:
        raise InvalidInput(
            f"expected an answer of finite numbers, got non-finite {bad} from these {inputs}: "
            "they are beyond what the canal can compute with",
            field=inputs.split(", ")[0],
        )


def check_obstacles(obstacles: Sequence[Any], field: str = "obstacles") -> None:
    """Every obstacle's points and lengths within :data:`canal_core.bounds.MAX_COORDINATE`
    (a scene put, or obstacles sent with a reproduction), before canal_core reads them."""
    for i, obstacle in enumerate(obstacles):
        _core_checked(bounds.check_obstacle_numbers, obstacle, f"{field}[{i}]")


def check_correction_inputs(directrix: FloatArray, radii: FloatArray, samples: Any, plan: Any,
                            timestamps: Any) -> None:
    """A correction's paths (``samples``, ``plan``) within
    :data:`canal_core.bounds.MAX_REACH` canal sizes of the canal and its times within
    :data:`canal_core.bounds.MAX_TIME`, before canal_core reads them; each bad row named."""
    centre, size = bounds.canal_extent(directrix, radii)
    for field, rows in (("samples", samples), ("plan", plan)):
        for i, row in enumerate(rows or ()):
            if len(row) != centre.shape[0]:
                continue  # the wrong width: canal_core names it
            _core_checked(lambda v, f: bounds.check_reach(v, centre, size, f), row,
                          f"{field}[{i}]")
    if timestamps is not None:
        _core_checked(bounds.check_times, timestamps, "timestamps")


def check_route(route: int | None, n_routes: int, field: str) -> int | None:
    """A route a request names, checked against the model's routes (None stays None)."""
    if route is not None and not 0 <= route < n_routes:
        raise InvalidInput(f"expected {field} in 0..{n_routes - 1} (the model has {n_routes} "
                           f"route{'s' if n_routes > 1 else ''}), got {route}", field=field)
    return route
