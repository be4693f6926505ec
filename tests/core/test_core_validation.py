"""Bad input raises a CanalError subclass naming the field; degenerate-but-valid input does not crash."""

from __future__ import annotations

import numpy as np
import pytest

import canal_core
from canal_core import DegenerateCanalError, InvalidInputError, datasets


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
        ([[[0, 0, 0], [1, 1]], [[0, 0, 0]]], {}, "demos[0]", "array of numbers"),
        ("abc", {}, "demos", "list of (T_j, D) arrays"),
    ],
)
def test_malformed_demonstrations_are_rejected(demos, kwargs, field, words) -> None:
    with pytest.raises(InvalidInputError) as err:
        canal_core.fit(demos, **kwargs)
    assert err.value.field == field
    assert words in str(err.value)


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
        ("decreasing", "increasing timestamps", "timestamps[1]"),
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


def test_errors_share_one_base() -> None:
    for cls in (InvalidInputError, DegenerateCanalError, canal_core.OutsideCanalError, canal_core.ModelFormatError):
        assert issubclass(cls, canal_core.CanalError)


def test_bad_points_for_queries() -> None:
    canal = canal_core.fit(good())
    with pytest.raises(InvalidInputError, match=r"expected start of shape \(3,\), got \(2,\)"):
        canal.reproduce([0.0, 1.0])
    with pytest.raises(InvalidInputError, match="points"):
        canal.contains(np.ones((5, 2)))
    with pytest.raises(InvalidInputError, match="outside"):
        canal.reproduce_detailed([0.0, 0.0, 0.0], outside="ignore")
