"""The wall's slope (F2) and the offset's pace (F3): a reproduction never jumps with a wall the
fit grew at one section, nor fades a start's offset faster than a demonstration moved."""

from __future__ import annotations

import numpy as np

import canal_core
from canal_core.tube import paced_offsets, wall_slope_shares


def test_the_wall_a_point_rides_has_a_slope_of_at_most_one_and_is_never_further_out() -> None:
    s = np.linspace(0.0, 1.0, 101)
    gentle = 0.3 + 0.2 * np.sin(3.0 * s)  # |dR/ds| <= 0.6: nothing to change
    assert np.allclose(wall_slope_shares(gentle, s), 1.0, rtol=0.0, atol=1e-12)
    jumpy = gentle.copy()
    jumpy[40:45] += 0.25  # sections grown to hold a sample of another stretch
    jumpy[70] *= 0.2
    shares = wall_slope_shares(jumpy, s)
    wall = shares * jumpy
    assert (shares <= 1.0 + 1e-12).all() and (shares > 0.0).all()
    assert (np.abs(np.diff(wall)) <= np.diff(s) + 1e-12).all()
    assert np.allclose(wall[:30], jumpy[:30])  # far enough before the grown sections


def test_paced_offsets_change_by_at_most_what_is_allowed_and_stay_inside() -> None:
    rng = np.random.default_rng(3)
    m = np.abs(rng.normal(0.2, 0.1, 60))
    allowed = rng.uniform(0.005, 0.02, 59)
    wall = np.full(60, 0.5)
    m[-1] = 0.0  # a landing
    paced = paced_offsets(m, allowed, wall)
    assert (paced <= np.maximum(m, wall) + 1e-15).all()  # inside stays inside
    assert (np.abs(np.diff(paced)) <= allowed + 1e-12).all()
    assert paced[-1] == 0.0
    # Already paced: unchanged.
    assert np.allclose(paced_offsets(paced, allowed, wall), paced, rtol=0.0, atol=1e-15)
    assert paced_offsets(np.zeros(0), np.zeros(0), np.zeros(0)).size == 0
    # Outside the wall (entering): neither raised nor pulled in earlier.
    entering = np.array([0.9, 0.8, 0.7, 0.3, 0.29])
    assert np.allclose(paced_offsets(entering, np.full(4, 0.02), np.full(5, 0.5))[:3], entering[:3])


def test_an_entry_cut_short_by_the_tube_comes_down_to_the_cut_at_the_demonstrations_pace() -> None:
    # The entry schedule falls by 0.05 a section; the tube's cap cuts it to 0.3 at the fourth
    # point. The points before come down to meet the cut at the allowed 0.1 (the first step,
    # from the start, is the reproduction's straight approach), not in one drop of 0.5 (the
    # cut itself, inside, is slowed from the landing back as any fade is).
    scheduled = np.array([0.9, 0.85, 0.8, 0.75, 0.7])
    capped = np.array([0.9, 0.85, 0.8, 0.3, 0.29])
    paced = paced_offsets(capped, np.full(4, 0.1), np.full(5, 0.5), scheduled)
    assert np.allclose(paced, [0.69, 0.59, 0.49, 0.39, 0.29])
    # Where the schedule itself falls faster than a demonstration stepped, it is kept.
    paced = paced_offsets(scheduled[[0, 1, 2]] - [0.0, 0.2, 0.4], np.full(2, 0.1), np.full(3, 0.2),
                          scheduled[[0, 1, 2]] - [0.0, 0.2, 0.4])
    assert np.allclose(paced, [0.9, 0.65, 0.4])


def test_paced_offsets_keep_a_path_that_has_entered_inside() -> None:
    # A start outside, entering while the wall widens and then narrows: lowering the rise
    # brings the second point inside; the third must not leave again.
    m = np.array([1.8, 2.0, 1.9, 1.0])
    wall = np.array([1.5, 1.9, 1.7, 1.7])
    paced = paced_offsets(m, np.full(3, 0.05), wall)
    first = int(np.flatnonzero(paced <= wall)[0])
    assert (paced[first:] <= wall[first:]).all()


def pressing_demo(j: int, n: int = 300) -> np.ndarray:
    """Down, up a little and down again at one place: a stroke that folds back over itself."""
    rng = np.random.default_rng(j)
    t = np.linspace(0.0, 1.0, n)
    z = np.interp(t, [0.0, 0.35, 0.6, 1.0], [0.0, -0.12, -0.05, -0.16]) + 0.01 * rng.normal()
    x = 0.04 * t + 0.02 * rng.normal() + 0.01 * np.sin(3.0 * t + j)
    y = 0.02 * rng.normal() + 0.01 * np.cos(4.0 * t + j)
    return np.column_stack([x, y, z])


def test_on_a_stroke_that_folds_back_the_offset_keeps_the_demonstrations_pace() -> None:
    demos = [pressing_demo(j) for j in range(6)]
    for k in range(len(demos)):
        canal = canal_core.fit(demos[:k] + demos[k + 1:])
        rep = canal.reproduce_detailed(demos[k][0])
        first = rep.section_index + 1
        path = rep.section_path
        sections = np.arange(first, first + path.shape[0])
        offset = np.linalg.norm(path - canal.directrix[sections], axis=1)
        steps = canal.section_steps[sections]
        allowed = np.minimum(steps[:-1], steps[1:])
        assert (np.abs(np.diff(offset)) <= allowed * (1.0 + 1e-9) + 1e-12).all(), k
        # Inside stays inside: from the first point inside on, every point is.
        assert canal.contains(rep.positions[rep.entry_index:]).all(), k
        assert (rep.ratios[rep.entry_index:] <= 1.0 + 1e-9).all(), k


def test_a_start_inside_whose_offset_the_demonstrations_forget_at_once_steps_off_at_their_pace() -> None:
    """Demonstrations that set off spread and meet within 3 % of the length: the learned
    persistence has the start's offset gone by the next section. The first step, from the
    start, is paced like the rest (F3 anchored at the start); before, it fell to the
    persistence's ratio at once, 2.7x the demonstrations' largest step there."""
    s = np.linspace(0.0, 1.0, 300)
    fade = np.clip(1.0 - s / 0.03, 0.0, 1.0)
    demos = [np.column_stack([s, o * fade + 0.002 * np.sin(3 * s + k), 0.2 * s**2 + 0.001 * k])
             for k, o in enumerate(np.linspace(-0.1, 0.1, 6))]
    canal = canal_core.fit(demos, n_samples=200)
    for x in (0.004, 0.008, 0.015):
        for y in (0.05, 0.08):
            result = canal.reproduce_detailed([x, y * (1.0 - x / 0.03), 0.0])
            assert result.inside and result.approach == 0
            first = float(np.linalg.norm(result.positions[1] - result.positions[0]))
            assert first <= 1.05 * canal.section_steps[result.section_index + 1], (x, y)
