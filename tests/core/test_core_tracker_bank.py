"""Tracker states held as arrays (``TrackerBank``): one pass per batch, the scalar answers."""

from __future__ import annotations

import numpy as np
import pytest
from core_data import helix_demos, sleeve_demos, tracker_starts

import canal_core
from canal_core import datasets
from canal_core.tracker_bank import VECTORISE_FROM, TrackerBank


def _check(got, k: int, e) -> None:
    assert (int(got.section_index[k]), bool(got.inside[k]), bool(got.done[k])) == (
        e.section_index, e.inside, e.done)
    np.testing.assert_allclose(got.target[k], e.target, rtol=1e-9, atol=1e-12)
    assert got.progress[k] == pytest.approx(e.progress, rel=1e-9, abs=1e-12)
    assert got.eta[k] == pytest.approx(e.eta, rel=1e-9, abs=1e-12)


@pytest.mark.parametrize("cross_section", ["circle", "ellipse"])
@pytest.mark.parametrize("demos", [sleeve_demos, helix_demos, datasets.task_one])
def test_bank_steps_equal_scalar_steps_along_whole_runs(demos, cross_section: str) -> None:
    canal = canal_core.fit(demos(), n_samples=120, cross_section=cross_section)
    rng = np.random.default_rng(3)
    b = 12
    x = tracker_starts(canal, b, rng)
    scalar = [canal.tracker(lookahead=2) for _ in range(b)]
    bank = TrackerBank(scalar[0].geometry, lookahead=2, capacity=4)  # grows on the way
    slots = [bank.add() for _ in range(b)]
    assert len(bank) == b
    for k in range(120):
        if k == 60:  # a push far ahead for a few robots, a reset for another
            x[:3] += 0.5 * (canal.directrix[-1] - canal.directrix[0])
            bank.reset(slots[5], 7)
            scalar[5].reset(7)
        # a varying subset each step, in shuffled order: slots are independent rows
        rows = rng.permutation(b)[: b if k % 3 else b // 2]
        expected = {int(r): scalar[r].step(x[r]) for r in rows}
        got = bank.step([slots[r] for r in rows], x[rows])
        for j, r in enumerate(rows):
            _check(got, j, expected[int(r)])
            state = bank.state(slots[r])
            assert state.index == scalar[r].state.index
            assert (state.eta is None) == (scalar[r].state.eta is None)
        x[rows] = x[rows] + 0.4 * (got.target - x[rows]) + 0.002 * rng.standard_normal(
            (len(rows), x.shape[1]))


def test_bank_carries_orientation_and_velocity_like_the_scalar_step() -> None:
    from scipy.spatial.transform import Rotation

    demos = sleeve_demos()
    quats = [Rotation.from_euler("z", np.linspace(0.0, 90.0, len(d))[:, None], degrees=True)
             .as_quat() for d in demos]
    times = [np.linspace(0.0, 2.0 + 0.1 * j, len(d)) for j, d in enumerate(demos)]
    canal = canal_core.fit(demos, orientations=quats, timestamps=times, n_samples=60)
    b = 2 * VECTORISE_FROM  # the vectorised pass
    x = tracker_starts(canal, b, np.random.default_rng(4))
    scalar = [canal.tracker(lookahead=2) for _ in range(b)]
    bank = TrackerBank(scalar[0].geometry, lookahead=2)
    slots = [bank.add() for _ in range(b)]
    for _ in range(30):
        expected = [t.step(p) for t, p in zip(scalar, x, strict=True)]
        got = bank.step(slots, x)
        assert got.orientation is not None and got.velocity is not None
        for k, e in enumerate(expected):
            _check(got, k, e)
            assert e.orientation is not None and e.velocity is not None
            np.testing.assert_allclose(got.orientation[k], e.orientation)
            np.testing.assert_allclose(got.velocity[k], e.velocity, rtol=1e-9, atol=1e-12)
        x = x + 0.5 * (got.target - x)


def test_bank_answers_far_and_overflowing_rows_outside_and_reuses_slots() -> None:
    canal = canal_core.fit(sleeve_demos(), n_samples=80)
    bank = TrackerBank(canal.tracker().geometry, lookahead=2)
    assert bank.step([], np.zeros((0, 3))).target.shape == (0, 3)
    slots = [bank.add() for _ in range(2 * VECTORISE_FROM)]
    a, b, c = slots[:3]
    far = np.repeat(canal.directrix[3:4], len(slots), axis=0)
    far[0], far[1] = [50.0, 50.0, 50.0], [1e308, 1e308, 1e308]
    for rows in (slots, slots[:3]):  # the vectorised pass, the scalar steps
        got = bank.step(rows, far[: len(rows)])
        assert not got.inside[0] and not got.inside[1] and got.inside[2:].all()
        assert (bank.index[rows] >= 0).all() and np.isfinite(got.target[2:]).all()
    bank.release(b)
    assert len(bank) == len(slots) - 1
    again = bank.add(5)
    assert again == b and bank.state(again).index == 5 and bank.state(again).eta is None


def test_a_seeded_slot_holds_a_glitch_after_it_and_a_far_seed_places_nothing() -> None:
    canal = canal_core.fit(sleeve_demos(), n_samples=80)
    bank = TrackerBank(canal.tracker().geometry, lookahead=2)
    slot = bank.add()
    robot = canal.directrix[20]
    assert bank.seed(slot, robot, 20)
    state = bank.state(slot)
    assert 19 <= state.index <= 21 and state.eta is not None  # placed with a plan
    # the next pose a glitch at the canal's end: held, not followed there
    got = bank.step([slot], canal.directrix[-1][None, :])
    assert not got.inside[0] and not got.done[0] and bank.state(slot).index == state.index
    # a seed far from the canal places nothing (no plan, the first section)
    assert not bank.seed(slot, np.full(3, 50.0), 40)
    assert bank.state(slot).index == 0 and bank.state(slot).eta is None
