"""Orientation along the canal: section means, carried start offsets, q/-q, checks, round trip."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import canal_core
from canal_core import InvalidInputError, ModelFormatError
from canal_core.orientation import angles_between, hemisphere_continuous, mean_orientations
from canal_core.preprocess import prepared_demonstration, prepared_rows

UR5E = Path(__file__).resolve().parent.parent / "data" / "ur5e_lab_demos.npz"
T = 120


def arc(j: int, t: int = T) -> np.ndarray:
    """A quarter circle at constant speed, translated per demo: arc-length phase = sample phase."""
    theta = np.linspace(0.0, np.pi / 2, t)
    off = 0.03 * (j - 2)
    return np.column_stack([np.cos(theta) + off, np.sin(theta) - off, 0.2 * theta + 0.5 * off])


def profile(t: int = T) -> Rotation:
    """A common orientation profile: a 90 deg tilt about y over the second half."""
    s = np.linspace(0.0, 1.0, t)
    return Rotation.from_euler("y", (np.pi / 2) * np.clip(2.0 * s - 1.0, 0.0, 1.0)[:, None])


def persistent_set(angles_deg: list[float]) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Demos whose orientation is the profile times a constant tool-frame offset about x."""
    demos, quats = [], []
    for j, a in enumerate(angles_deg):
        q = (profile() * Rotation.from_euler("x", a, degrees=True)).as_quat()
        q[1::3] *= -1.0  # q and -q mixed inside a demo, as drivers do
        demos.append(arc(j))
        quats.append(q)
    return demos, quats


def test_section_means_are_markley_means_and_ignore_signs() -> None:
    rng = np.random.default_rng(3)
    aligned = Rotation.random(5 * 7, random_state=4).as_quat().reshape(5, 7, 4)
    # Keep them in one neighbourhood, where the mean is well defined.
    aligned = (Rotation.from_rotvec(0.4 * rng.standard_normal((35, 3))) * Rotation.from_quat([0, 0, 0.3, 1.0])
               ).as_quat().reshape(5, 7, 4)
    means = mean_orientations(aligned)
    flipped = aligned * np.where(rng.random((5, 7, 1)) < 0.5, -1.0, 1.0)
    means_flipped = mean_orientations(flipped)
    for k in range(7):
        expected = Rotation.from_quat(aligned[:, k]).mean().as_quat()
        assert np.degrees(angles_between(means[k], expected)) < 1e-6
    assert np.allclose(means, means_flipped, atol=1e-12)
    assert np.all(np.einsum("kd,kd->k", means[1:], means[:-1]) > 0.0)  # hemisphere-continuous


def test_reproduction_without_start_orientation_follows_the_section_means() -> None:
    demos, quats = persistent_set([-10.0, -5.0, 0.0, 5.0, 10.0])
    # Resampled evenly (the demos share one pace): section k is the profile's sample k.
    canal = canal_core.fit(demos, orientations=quats, n_samples=60, alignment="spline")
    assert canal.has_orientation and canal.orientation is not None
    rep = canal.reproduce_detailed(demos[2][0])
    assert rep.orientations is not None and rep.orientation_eta is None
    assert rep.orientations.shape == (rep.positions.shape[0], 4)
    assert np.allclose(np.linalg.norm(rep.orientations, axis=1), 1.0)
    # The symmetric offsets average out: the means are the profile itself.
    truth = profile(60).as_quat()
    assert np.degrees(angles_between(rep.orientations[1:], truth[61 - rep.positions.shape[0]:])).max() < 1.0
    assert np.degrees(canal.orientation.spreads).max() == pytest.approx(10.0, abs=0.3)


def test_a_persistent_start_offset_is_carried_to_the_end() -> None:
    demos, quats = persistent_set([-12.0, -4.0, 4.0, 12.0])
    canal = canal_core.fit(demos, orientations=quats, n_samples=60, alignment="spline")
    start_q = (profile()[0] * Rotation.from_euler("x", 8.0, degrees=True)).as_quat()
    rep = canal.reproduce_detailed(arc(1)[0], start_orientation=-start_q)
    assert rep.orientations is not None
    assert np.allclose(rep.orientations[0], -start_q)  # the start's own sign is kept
    truth = (profile(60) * Rotation.from_euler("x", 8.0, degrees=True)).as_quat()
    passed = truth[61 - rep.positions.shape[0]:]
    assert np.degrees(angles_between(rep.orientations[1:], passed)).max() < 1.0
    assert rep.orientation_eta == pytest.approx(8.0 / 12.0, rel=0.05)
    steps = np.degrees(angles_between(rep.orientations[1:], rep.orientations[:-1]))
    assert steps.max() < 5.0  # no jump between the start and the path


def test_an_offset_the_demos_did_not_keep_blends_back_to_the_mean() -> None:
    # Each demo starts rotated about x, but all end on the same orientation profile.
    demos, quats = [], []
    s = np.linspace(0.0, 1.0, T)
    for j, a in enumerate([-12.0, -4.0, 4.0, 12.0]):
        fade = np.clip(1.0 - 3.0 * s, 0.0, 1.0)
        demos.append(arc(j))
        quats.append((profile() * Rotation.from_euler("x", a * fade[:, None], degrees=True)).as_quat())
    canal = canal_core.fit(demos, orientations=quats, n_samples=60, alignment="spline")
    start_q = Rotation.from_euler("x", 8.0, degrees=True).as_quat()
    rep = canal.reproduce_detailed(arc(1)[0], start_orientation=start_q)
    assert rep.orientations is not None
    last = profile(60).as_quat()[-20:]
    assert np.degrees(angles_between(rep.orientations[-20:], last)).max() < 0.5


def test_signs_of_the_demo_quaternions_do_not_change_the_model() -> None:
    demos, quats = persistent_set([-10.0, 0.0, 10.0])
    flipped = [q * np.where(np.arange(len(q)) % 2 == 0, -1.0, 1.0)[:, None] for q in quats]
    a = canal_core.fit(demos, orientations=quats, n_samples=40).orientation
    b = canal_core.fit(demos, orientations=flipped, n_samples=40).orientation
    assert a is not None and b is not None
    assert np.abs(np.einsum("kd,kd->k", a.means, b.means)) == pytest.approx(np.ones(40))
    assert np.allclose(a.offsets, b.offsets, atol=1e-9)


def test_orientations_follow_the_rows_kept_with_the_positions() -> None:
    demo = np.vstack([np.zeros((5, 3)), arc(0), np.repeat(arc(0)[-1:], 7, axis=0)])
    demo[10] = demo[9]  # an exact repeat inside
    rows = prepared_rows(demo, field="demo")
    assert np.array_equal(demo[rows], prepared_demonstration(demo, field="demo")[0])
    # A still head that rotates must not pull the start section's orientation.
    demos, quats = persistent_set([-5.0, 0.0, 5.0])
    still = np.repeat(demos[0][:1], 30, axis=0)
    demos[0] = np.vstack([still, demos[0]])
    quats[0] = np.vstack([Rotation.from_euler("z", np.linspace(0, 170, 30)[:, None], degrees=True).as_quat(), quats[0]])
    canal = canal_core.fit(demos, orientations=quats, n_samples=40)
    assert canal.orientation is not None
    assert np.degrees(canal.orientation.spreads[0]) < 6.0


def test_dtw_alignment_learns_orientation_too() -> None:
    demos, quats = persistent_set([-10.0, 0.0, 10.0])
    canal = canal_core.fit(demos, orientations=quats, n_samples=40, alignment="dtw")
    assert canal.orientation is not None
    assert np.degrees(canal.orientation.spreads).max() < 12.0


@pytest.mark.parametrize(
    ("orientations", "field"),
    [
        ("not quaternions", "orientations"),
        ([np.zeros((T, 4))], "orientations"),  # one array for two demos
        (None, None),
    ],
)
def test_bad_orientation_sets_name_the_field(orientations: object, field: str | None) -> None:
    demos, _ = persistent_set([-5.0, 5.0])
    if field is None:
        assert canal_core.fit(demos, orientations=orientations, n_samples=20).orientation is None
        return
    with pytest.raises(InvalidInputError) as err:
        canal_core.fit(demos, orientations=orientations, n_samples=20)
    assert err.value.field == field


def test_bad_quaternions_name_the_demo_and_row() -> None:
    demos, quats = persistent_set([-5.0, 5.0])
    bad = [quats[0], quats[1].copy()]
    bad[1][7] *= 2.0
    with pytest.raises(InvalidInputError, match="norm") as err:
        canal_core.fit(demos, orientations=bad, n_samples=20)
    assert err.value.field == "orientations[1][7]"
    bad[1] = quats[1].copy()
    bad[1][3, 2] = np.nan
    with pytest.raises(InvalidInputError) as err:
        canal_core.fit(demos, orientations=bad, n_samples=20)
    assert err.value.field == "orientations[1]"
    with pytest.raises(InvalidInputError, match=r"shape \(120, 4\)"):
        canal_core.fit(demos, orientations=[quats[0], quats[1][:, :3]], n_samples=20)
    # Loosely normalised float32 quaternions are accepted and renormalised.
    loose = [q * 1.0005 for q in quats]
    canal = canal_core.fit(demos, orientations=loose, n_samples=20)
    assert canal.orientation is not None
    assert np.allclose(np.linalg.norm(canal.orientation.means, axis=1), 1.0)


@pytest.mark.parametrize("value", [[0, 0, 0, 2], [0, 0, 1], [0, 0, np.inf, 1], "x"])
def test_bad_start_orientation_is_refused(value: object) -> None:
    demos, quats = persistent_set([-5.0, 5.0])
    canal = canal_core.fit(demos, orientations=quats, n_samples=20)
    with pytest.raises(InvalidInputError) as err:
        canal.reproduce_detailed(demos[0][0], start_orientation=value)
    assert err.value.field == "start_orientation"


def test_model_without_orientation_ignores_a_start_orientation() -> None:
    demos, _ = persistent_set([-5.0, 5.0])
    canal = canal_core.fit(demos, n_samples=20)
    rep = canal.reproduce_detailed(demos[0][0], start_orientation=[0, 0, 0, 1])
    assert not canal.has_orientation and rep.orientations is None
    assert canal.tracker().step(demos[0][3]).orientation is None


def test_round_trip_and_old_models() -> None:
    demos, quats = persistent_set([-10.0, 0.0, 10.0])
    canal = canal_core.fit(demos, orientations=quats, n_samples=30)
    data = json.loads(json.dumps(canal.to_dict()))
    back = canal_core.Canal.from_dict(data)
    assert back.orientation is not None and canal.orientation is not None
    assert np.array_equal(back.orientation.means, canal.orientation.means)
    assert np.array_equal(back.orientation.offsets, canal.orientation.offsets)
    q0 = quats[0][0]
    assert np.array_equal(back.reproduce_detailed(demos[0][0], start_orientation=q0).orientations,
                          canal.reproduce_detailed(demos[0][0], start_orientation=q0).orientations)
    old = dict(data)
    del old["orientation"]  # written before orientation existed
    assert canal_core.Canal.from_dict(old).orientation is None
    broken = dict(data, orientation={"means": data["orientation"]["means"][:-1],
                                     "offsets": data["orientation"]["offsets"]})
    with pytest.raises(ModelFormatError) as err:
        canal_core.Canal.from_dict(broken)
    assert err.value.field == "orientation"


def test_tracker_targets_carry_the_target_sections_mean() -> None:
    demos, quats = persistent_set([-10.0, 0.0, 10.0])
    canal = canal_core.fit(demos, orientations=quats, n_samples=40)
    assert canal.orientation is not None
    tracker = canal.tracker(lookahead=2)
    target = tracker.step(demos[1][30])
    assert target.orientation is not None
    assert np.array_equal(target.orientation, canal.orientation.means[target.section_index + 2])


def test_hemisphere_continuous_follows_the_reference() -> None:
    q = Rotation.from_euler("z", np.linspace(0, 300, 20)[:, None], degrees=True).as_quat()
    q[::2] *= -1.0
    out = hemisphere_continuous(q, reference=-q[1])
    assert np.all(np.einsum("td,td->t", out[1:], out[:-1]) > 0.0)
    assert out[0] @ -q[1] > 0.0
    assert np.allclose(np.abs(np.einsum("td,td->t", out, q)), 1.0)


def test_real_ur5e_demos_with_mixed_quaternion_signs() -> None:
    data = np.load(UR5E)
    demos = [data[f"demo{i}_pos"] for i in range(5)]
    quats = [data[f"demo{i}_quat"] for i in range(5)]
    assert any((q[:, 3] < 0).any() and (q[:, 3] > 0).any() for q in quats)
    canal = canal_core.fit(demos[:4], orientations=quats[:4])
    assert canal.orientation is not None
    rep = canal.reproduce_detailed(demos[4][0], start_orientation=quats[4][0])
    assert rep.orientations is not None
    assert np.allclose(np.linalg.norm(rep.orientations, axis=1), 1.0)
    assert np.allclose(rep.orientations[0], quats[4][0] / np.linalg.norm(quats[4][0]))
    steps = np.degrees(angles_between(rep.orientations[1:], rep.orientations[:-1]))
    assert steps.max() < 5.0
    assert np.all(np.einsum("td,td->t", rep.orientations[1:], rep.orientations[:-1]) > 0.0)
    # The held-out demo stays within the demos' spread of the mean for most of the way.
    spreads = np.degrees(canal.orientation.spreads)
    assert 2.0 < np.median(spreads) < 30.0


def test_slerped_matches_scipy_and_takes_the_short_way() -> None:
    from scipy.spatial.transform import Slerp

    from canal_core.orientation import slerped

    a, b = Rotation.from_euler("xyz", [0.1, 0.4, -0.2]).as_quat(), Rotation.from_euler("z", 1.3).as_quat()
    shares = np.array([0.0, 0.25, 0.5, 1.0])
    expected = Slerp([0.0, 1.0], Rotation.from_quat([a, b]))(shares)
    for q in (b, -b):  # either sign of the end: the same rotations, from a's hemisphere
        got = slerped(a, q, shares)
        assert np.degrees(angles_between(got, expected.as_quat())).max() < 1e-9
        assert np.all(got @ a > 0.0)
    np.testing.assert_allclose(slerped(a, a, shares), np.tile(a, (4, 1)), atol=1e-15)
