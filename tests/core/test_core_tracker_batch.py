"""The batched tracker step (many streams, one numpy pass) answers what the scalar one does."""

from __future__ import annotations

import numpy as np
import pytest
from core_data import helix_demos, sleeve_demos, tracker_starts

import canal_core
from canal_core import datasets
from canal_core.tracker import Tracker, TrackerState
from canal_core.tracker_batch import step_trackers, tracker_steps


@pytest.mark.parametrize("cross_section", ["circle", "ellipse"])
@pytest.mark.parametrize("demos", [sleeve_demos, helix_demos, datasets.task_one])
def test_batched_steps_equal_scalar_steps_along_whole_runs(demos, cross_section: str) -> None:
    canal = canal_core.fit(demos(), n_samples=120, cross_section=cross_section)
    rng = np.random.default_rng(3)
    b = 12
    x = tracker_starts(canal, b, rng)
    scalar = [canal.tracker(lookahead=2) for _ in range(b)]
    batched = [Tracker(scalar[0].geometry, lookahead=2) for _ in range(b)]
    for k in range(120):
        if k == 60:  # a push far ahead for a few robots, a reset for another
            x[:3] += 0.5 * (canal.directrix[-1] - canal.directrix[0])
            batched[5].reset(7)
            scalar[5].reset(7)
        expected = [t.step(p) for t, p in zip(scalar, x, strict=True)]
        got = step_trackers(batched, x)
        for e, g in zip(expected, got, strict=True):
            assert (g.section_index, g.inside, g.done) == (e.section_index, e.inside, e.done)
            np.testing.assert_allclose(g.target, e.target, rtol=1e-9, atol=1e-12)
            assert g.progress == pytest.approx(e.progress, rel=1e-9, abs=1e-12)
            assert g.eta == pytest.approx(e.eta, rel=1e-9, abs=1e-12)
        for s, t in zip(scalar, batched, strict=True):
            assert s.state.index == t.state.index
        targets = np.array([e.target for e in expected])
        x = x + 0.4 * (targets - x) + 0.002 * rng.standard_normal(x.shape)


def test_batched_step_handles_empty_and_far_away_rows() -> None:
    canal = canal_core.fit(sleeve_demos(), n_samples=80)
    geometry = canal.tracker().geometry
    assert tracker_steps(geometry, [], np.zeros((0, 3))) == ([], [])
    far = np.array([[50.0, 50.0, 50.0], [1e308, 1e308, 1e308], canal.directrix[3]])
    targets, states = tracker_steps(geometry, [TrackerState(0)] * 3, far, 2)
    assert not targets[0].inside and not targets[1].inside
    assert targets[2].inside
    assert all(s.index >= 0 for s in states)


def test_batched_steps_carry_the_same_orientation_and_velocity_as_scalar_steps() -> None:
    """The batched path once dropped the orientation the scalar step gives (and the scalar
    step passed it positionally into ``velocity``)."""
    from scipy.spatial.transform import Rotation

    demos = sleeve_demos()
    quats = [Rotation.from_euler("z", np.linspace(0.0, 90.0, len(d))[:, None], degrees=True).as_quat() for d in demos]
    canal = canal_core.fit(demos, orientations=quats, n_samples=60)
    x = tracker_starts(canal, 5, np.random.default_rng(4))
    scalar = [canal.tracker() for _ in range(5)]
    batched = [Tracker(scalar[0].geometry) for _ in range(5)]
    expected = [t.step(p) for t, p in zip(scalar, x, strict=True)]
    got = step_trackers(batched, x)
    for e, g in zip(expected, got, strict=True):
        assert e.orientation is not None and g.orientation is not None
        assert e.orientation.shape == (4,)
        np.testing.assert_allclose(g.orientation, e.orientation)
        assert (e.velocity is None) == (g.velocity is None)
