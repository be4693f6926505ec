"""Bad input raises a CanalError subclass naming the field, what was expected and what came;
degenerate-but-valid input does not crash."""

from __future__ import annotations

import re

import numpy as np
import pytest

import canal_core
from canal_core import DegenerateCanalError, InvalidInputError, bounds, datasets, validation


def good() -> list[np.ndarray]:
    return datasets.task_one(n_points=30)


@pytest.mark.parametrize(
    ("demos", "kwargs", "field", "words"),
    [
        ([np.zeros((10, 3))], {}, "demos", "at least 2 demonstrations"),
        ([np.ones((10, 3)), np.ones((3, 3))], {}, "demos[1]", "at least 4 points"),
        ([np.ones((10, 3)), np.ones((10, 2))], {}, "demos", "same dimension"),
        ([np.ones((10, 4)), np.ones((10, 4))], {}, "demos[0]", "shape (T, D)"),
        ([np.full((10, 3), np.nan), np.ones((10, 3))], {}, "demos[0]", "NaN or Inf"),
        ([[[0, 0, 0], [1, 1]], [[0, 0, 0]]], {}, "demos[0][1]", "got 2 values at row 1"),
        ("abc", {}, "demos", "list of (T_j, D) arrays"),
    ],
)
def test_malformed_demonstrations_are_rejected(demos, kwargs, field, words) -> None:
    with pytest.raises(InvalidInputError) as err:
        canal_core.fit(demos, **kwargs)
    assert err.value.field == field
    assert words in str(err.value)


@pytest.mark.parametrize(
    ("row", "field", "words"),
    [
        ([1.0, 1.0], "positions[1]", "expected 3 values per row of positions (as row 0 has), got 2 values at row 1"),
        (None, "positions[1]", "expected positions[1] as a row of 3 numbers, got null"),
        ([1.0, [1.0], 1.0], "positions[1][1]", "expected a number at positions[1][1], got list"),
        ([1.0, {}, 1.0], "positions[1][1]", "got an object"),
    ],
)
def test_a_malformed_row_is_named_by_index_not_by_numpy(row: object, field: str, words: str) -> None:
    rows: list[object] = [[0.0, 0.0, 0.0], row, [2.0, 2.0, 2.0], [3.0, 3.0, 3.0]]
    with pytest.raises(InvalidInputError) as err:
        validation.check_positions(rows)
    assert err.value.field == field and words in str(err.value)
    assert "inhomogeneous" not in str(err.value)


def test_a_malformed_time_stamp_is_named_by_index() -> None:
    with pytest.raises(InvalidInputError) as err:
        validation.check_timestamps([0.0, 0.1, [0.2], 0.3], 4)
    assert err.value.field == "timestamps[2]" and "expected a number at timestamps[2], got list" in str(err.value)


def test_inf_is_rejected_with_row() -> None:
    demos = good()
    demos[2] = demos[2].copy()
    demos[2][7, 1] = np.inf
    with pytest.raises(InvalidInputError, match="row 7"):
        canal_core.fit(demos)


@pytest.mark.parametrize(
    ("timestamps", "words", "field"),
    [
        ("bad-length", "shape", "timestamps[1]"),
        ("decreasing", "increasing timestamps\\[1\\]", "timestamps[1]"),
        ("reset", "time goes back for more than one sample", "timestamps[1]"),
        ("count", "one per demo", "timestamps"),
    ],
)
def test_bad_timestamps(timestamps: str, words: str, field: str) -> None:
    demos = good()
    times = [np.linspace(0, 1, d.shape[0]) for d in demos]
    if timestamps == "bad-length":
        times[1] = times[1][:-1]
    elif timestamps == "decreasing":
        times[1] = times[1][::-1]
    elif timestamps == "reset":  # a clock reset half-way: time restarts at 0
        times[1][15:] -= times[1][15]
    else:
        times = times[:2]
    with pytest.raises(InvalidInputError, match=words) as err:
        canal_core.fit(demos, timestamps=times)
    assert err.value.field == field


def test_equal_and_isolated_out_of_order_timestamps_are_repaired() -> None:
    # Polling loggers stamp two rows alike; a late packet lands one sample out of order.
    demos = good()
    times = [np.linspace(0, 1, d.shape[0]) for d in demos]
    times[1][5] = times[1][4]
    times[2][10] = times[2][3]
    canal = canal_core.fit(demos, timestamps=times)
    assert canal.contains(np.vstack([demos[0], demos[3]])).mean() > 0.95


@pytest.mark.parametrize(
    ("option", "value"),
    [("cross_section", "square"), ("frames", "random"), ("alignment", "x"), ("directrix", "median"), ("n_samples", 1), ("n_samples", 2.5)],
)
def test_bad_options(option: str, value: object) -> None:
    with pytest.raises(InvalidInputError) as err:
        canal_core.fit(good(), **{option: value})
    assert err.value.field == option


@pytest.mark.parametrize("kind", ["spline", "ellipse"])
def test_spline_and_ellipse_need_three_demos(kind: str) -> None:
    # Two demos fix one axis of a section; the ellipse used to crash (singular Khachiyan
    # scatter) and would otherwise have a made-up minor axis.
    with pytest.raises(InvalidInputError, match="at least 3 demonstrations") as err:
        canal_core.fit(good()[:2], cross_section=kind)
    assert err.value.field == "cross_section"


def test_ellipse_with_collinear_crossings_is_thin_not_singular() -> None:
    # Three demos in one plane: every section's crossings are collinear.
    t = np.linspace(0.0, 1.0, 60)
    demos = [np.column_stack([t, 0.3 * np.sin(np.pi * t) + dy, 0.0 * t]) for dy in (-0.02, 0.0, 0.02)]
    canal = canal_core.fit(demos, cross_section="ellipse")
    axes = canal.sections.params["axes"]
    assert np.all(np.isfinite(axes)) and axes.min() > 0.0
    assert canal.contains(np.vstack(demos)).mean() > 0.95


def test_identical_demos_are_degenerate() -> None:
    demo = good()[0]
    with pytest.raises(DegenerateCanalError, match="identical"):
        canal_core.fit([demo, demo.copy(), demo.copy()])


def test_still_demos_are_degenerate() -> None:
    with pytest.raises(InvalidInputError, match="distinct moving samples") as err:
        canal_core.fit([np.ones((10, 3)), np.ones((10, 3))])
    assert "all 10 samples are identical" in str(err.value) and err.value.field == "demos[0]"


def test_zero_radius_sections_and_collinear_demos_do_not_crash() -> None:
    # Two demos that meet at both ends (zero radius there) and lie in one plane (collinear
    # crossings): every kind must fit, reproduce and mesh without NaN.
    x = np.linspace(0, 1, 50)
    bump = np.sin(np.pi * x) * 0.1
    demos = [np.column_stack([x, bump, 0 * x]), np.column_stack([x, -bump, 0 * x])]
    middle = np.column_stack([x, 0 * x, 0 * x])
    for kind, ds in (("circle", demos), ("mec", demos), ("ellipse", [*demos, middle])):
        canal = canal_core.fit(ds, cross_section=kind)
        assert np.isfinite(canal.radii).all()
        path = canal.reproduce([0.5, 0.05, 0.0])
        assert np.isfinite(path).all()
        assert np.isfinite(canal.mesh().vertices).all()


def _two_demos() -> list[np.ndarray]:
    return good()[:2]


# (validator, call, field, what it expected, what it got): every message says all three.
VALIDATOR_CASES = [
    ("check_finite", lambda: validation.check_finite(np.array([[0.0, 0.0], [1.0, np.nan]]), "demos[0]"),
     "demos[0]", "expected finite demos[0]", "got NaN or Inf at row 1"),
    ("check_positions", lambda: validation.check_positions(np.ones((5, 4)), "demos[2]"),
     "demos[2]", "expected demos[2] of shape (T, D) with D in {2, 3}", "got (5, 4)"),
    ("check_positions", lambda: validation.check_positions(np.ones((3, 3)), "demos[1]"),
     "demos[1]", "expected at least 4 points in demos[1]", "got 3"),
    ("check_positions", lambda: validation.check_positions(np.ones((6, 2)), "positions", dim=3),
     "positions", "expected positions of shape (T, 3), got (6, 2)", "got (6, 2)"),
    ("check_positions", lambda: validation.check_positions([[0, 1, 2], [3, 4]], "demos[0]"),
     "demos[0][1]", "expected 3 values per row of demos[0]", "got 2 values at row 1"),
    ("check_positions", lambda: validation.check_positions({"x": 1}, "demos[0]"),
     "demos[0]", "expected demos[0] as an array of numbers", "got dict"),
    ("check_timestamps", lambda: validation.check_timestamps(np.arange(4.0), 5, "timestamps[1]"),
     "timestamps[1]", "expected timestamps[1] of shape (5,)", "got (4,)"),
    ("check_timestamps", lambda: validation.check_timestamps([0, 1, np.inf], 3, "timestamps[0]"),
     "timestamps[0]", "expected finite timestamps[0]", "got NaN or Inf at row 2"),
    ("check_demonstrations", lambda: validation.check_demonstrations("abc"),
     "demos", "expected demos as a list of (T_j, D) arrays", "got str"),
    ("check_demonstrations", lambda: validation.check_demonstrations([np.ones((10, 3))]),
     "demos", "expected at least 2 demonstrations in demos", "got 1"),
    ("check_demonstrations",
     lambda: validation.check_demonstrations([np.ones((10, 3)), np.ones((10, 2))]),
     "demos", "expected every demonstration in demos to have the same dimension D",
     "got shapes [(10, 3), (10, 2)]"),
    ("check_demonstrations",
     lambda: validation.check_demonstrations(_two_demos(), timestamps=[np.arange(30.0)]),
     "timestamps", "expected timestamps as a list of 2 arrays (one per demo)", "got 1"),
    ("check_point", lambda: validation.check_point([0.0, 1.0], 3),
     "start", "expected start of shape (3,)", "got (2,)"),
    ("check_point", lambda: validation.check_point([0.0, np.nan], 2, "goal"),
     "goal", "expected finite goal", "got NaN or Inf"),
    ("check_points", lambda: validation.check_points(np.ones((5, 2)), 3),
     "points", "expected points of shape (M, 3)", "got (5, 2)"),
    ("check_choice", lambda: validation.check_choice("square", ("circle", "mec"), "cross_section"),
     "cross_section", "expected cross_section to be one of 'circle', 'mec'", "got 'square'"),
    ("check_int", lambda: validation.check_int(2.5, 2, "n_samples"),
     "n_samples", "expected n_samples as an integer", "got float"),
    ("check_int", lambda: validation.check_int(True, 2, "n_samples"),
     "n_samples", "expected n_samples as an integer", "got bool"),
    ("check_int", lambda: validation.check_int(1, 2, "n_samples", 10),
     "n_samples", "expected n_samples >= 2 and <= 10", "got 1"),
    ("check_positive", lambda: validation.check_positive(0.0, "duration"),
     "duration", "expected duration as a finite number > 0", "got 0.0"),
    ("check_positive", lambda: validation.check_positive("2", "duration"),
     "duration", "expected duration as a number", "got str"),
    ("check_fraction", lambda: validation.check_fraction(0.5, "frame_smoothing"),
     "frame_smoothing", "expected frame_smoothing in [0, 0.25]", "got 0.5"),
    ("check_fraction", lambda: validation.check_fraction(None, "frame_smoothing"),
     "frame_smoothing", "expected frame_smoothing as a number", "got NoneType"),
    ("check_quaternions", lambda: validation.check_quaternions(np.ones((3, 3)), 3, "orientations[0]"),
     "orientations[0]", "expected orientations[0] of shape (3, 4)", "got (3, 3)"),
    ("check_quaternions",
     lambda: validation.check_quaternions([[0, 0, 0, 1], [0, 0, 0, 2]], None, "orientations"),
     "orientations[1]", "expected unit quaternions in orientations", "got norm 2 at row 1"),
    ("check_quaternion", lambda: validation.check_quaternion([0.0, 0.0, 1.0]),
     "start_orientation", "expected start_orientation of shape (4,)", "got (3,)"),
    ("check_quaternion", lambda: validation.check_quaternion([0.0, 0.0, 0.0, 0.5]),
     "start_orientation", "expected start_orientation as a unit quaternion", "got norm 0.5"),
    ("check_demonstration_orientations",
     lambda: validation.check_demonstration_orientations([np.tile([0, 0, 0, 1.0], (30, 1))],
                                                         _two_demos()),
     "orientations", "expected orientations as a list of 2 (T_j, 4) arrays (one per demo)",
     "got 1"),
]


@pytest.mark.parametrize(("validator", "call", "field", "expected", "got"), VALIDATOR_CASES,
                         ids=[f"{c[0]}-{i}" for i, c in enumerate(VALIDATOR_CASES)])
def test_validator_message_names_field_expected_and_got(validator, call, field, expected,
                                                        got) -> None:
    with pytest.raises(InvalidInputError) as err:
        call()
    message = str(err.value)
    assert err.value.field == field
    assert field.split("[")[0] in message, message
    assert message.startswith("expected ") and expected in message, message
    assert got in message and message.index(got) > message.index(expected), message


def test_every_validator_has_a_message_case() -> None:
    validators = {name for name, value in vars(validation).items()
                  if name.startswith("check_") and callable(value)}
    covered = {case[0] for case in VALIDATOR_CASES}
    assert validators - covered == set(), "add a row to VALIDATOR_CASES for each new check_*"
    assert covered <= validators


def test_every_raised_error_is_caught_as_canal_error() -> None:
    # The one base class is what callers (the service's error table) catch: the real errors
    # raised by real calls, not the class tree, are what must share it.
    canal = canal_core.fit(good())
    demo = good()[0]
    raised: dict[type, canal_core.CanalError] = {}
    calls = [
        lambda: canal_core.fit([demo]),
        lambda: canal_core.fit([demo, demo.copy(), demo.copy()]),
        lambda: canal.reproduce_detailed(canal.directrix[0] + 5.0, outside="raise"),
        lambda: canal_core.Canal.from_dict({"format": "something-else"}),
    ]
    for call in calls:
        try:
            call()
        except canal_core.CanalError as exc:
            raised[type(exc)] = exc
    assert set(raised) == {InvalidInputError, DegenerateCanalError,
                           canal_core.OutsideCanalError, canal_core.ModelFormatError}
    assert all(str(exc) for exc in raised.values())
    assert raised[InvalidInputError].field == "demos"
    assert raised[canal_core.OutsideCanalError].field == "start"


def test_bad_points_for_queries() -> None:
    canal = canal_core.fit(good())
    with pytest.raises(InvalidInputError, match=r"expected start of shape \(3,\), got \(2,\)"):
        canal.reproduce([0.0, 1.0])
    with pytest.raises(InvalidInputError, match="points"):
        canal.contains(np.ones((5, 2)))
    with pytest.raises(InvalidInputError, match="outside"):
        canal.reproduce_detailed([0.0, 0.0, 0.0], outside="ignore")


@pytest.mark.parametrize("kwargs,field,words", [
    # the library drew a two-point path from 1e200 (or 1e7) straight to the canal's end,
    # which the service refuses: the bounds of canal_core.bounds hold for every caller
    ({"start": [1e200, 0.0, 0.0]}, "start", "within +-1e+15"),
    ({"start": [1e7, 0.0, 0.0]}, "start", "canal sizes"),
    ({"start": [0.0, 1.0, 0.0], "goal": [0.0, 1e9, 0.0]}, "goal", "canal sizes"),
    ({"start": [0.0, 1.0, 0.0], "duration": 1e-6}, "duration", "between 0.001 s and 1e+06 s"),
    ({"start": [0.0, 1.0, 0.0], "duration": 1e9}, "duration", "between 0.001 s and 1e+06 s"),
])
def test_a_query_beyond_the_canal_s_bounds_is_refused_by_the_library_too(
        kwargs: dict, field: str, words: str) -> None:
    canal = canal_core.fit(good())
    with pytest.raises(InvalidInputError, match=re.escape(words)) as caught:
        canal.reproduce_detailed(**kwargs)
    assert caught.value.field == field
    routes = canal_core.routes.fit_routes(good())
    with pytest.raises(InvalidInputError, match=re.escape(words)):
        routes.reproduce_detailed(**kwargs)


@pytest.mark.parametrize("pose,words", [
    # a NaN first pose was answered inside the canal, at eta 0 and progress NaN
    ([np.nan, 0.0, 0.0], "finite"),
    ([np.inf, 0.0, 0.0], "finite"),
    # and a 2-D pose of a 3-D canal was numpy's "matmul: Input operand 1 has a mismatch"
    ([0.0, 0.0], "shape (3,)"),
])
def test_a_tracker_refuses_a_pose_that_is_no_point_of_its_space(pose: list, words: str) -> None:
    canal = canal_core.fit(good())
    tracker = canal.tracker()
    with pytest.raises(InvalidInputError, match=re.escape(words)) as caught:
        tracker.step(np.array(pose))
    assert caught.value.field == "position"
    assert tracker.state.index == 0 and tracker.state.eta is None  # nothing changed


@pytest.mark.parametrize("key,value", [
    # numpy's "all input arrays must have the same shape" when the model was built
    ("binormals", lambda d: d["binormals"][:3]),
    # numpy's "operands could not be broadcast together" at the first reproduction
    ("section_points", lambda d: d["section_points"][:3]),
    ("directrix", lambda d: [[float("nan")] * len(d["directrix"][0])] + d["directrix"][1:]),
    ("section_points", lambda d: [[[float("inf")] * 2] * len(d["section_points"][0])]
     + d["section_points"][1:]),
])
def test_a_model_file_with_arrays_that_do_not_fit_is_refused_naming_them(key: str, value) -> None:
    data = canal_core.fit(good()).to_dict()
    with pytest.raises(canal_core.ModelFormatError) as caught:
        canal_core.Canal.from_dict({**data, key: value(data)})
    assert caught.value.field == key


@pytest.mark.parametrize("call,got", [
    (lambda: bounds.check_duration(1_000_000.5), "1000000.5"),
    (lambda: bounds.check_duration(0.0009999999), "0.0009999999"),
    (lambda: validation.check_quaternion([0.0, 0.0, 0.0, 1.0010001]), "1.0010001"),
    (lambda: validation.check_quaternion([0.0, 0.0, 0.0, 2.0]), "norm 2"),
])
def test_a_value_just_past_a_bound_is_not_shown_as_the_bound(call, got: str) -> None:
    """Rounded to six digits, 1,000,000.5 s read "got 1e+06" beside "between ... and
    1e+06 s": the message must show what tells the value from the bound."""
    with pytest.raises(InvalidInputError) as info:
        call()
    assert got in info.value.message, info.value.message
