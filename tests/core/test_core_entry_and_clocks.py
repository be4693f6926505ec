"""Starts outside the canal (the learned entry) and the clock a fit aligns by."""

from __future__ import annotations

import numpy as np
import pytest

import canal_core
from canal_core.clocks import (
    STEADY_JITTER,
    chosen_clock,
    jitter_window,
    steady_index_clock,
    step_jitter,
    timing_spread,
)
from canal_core.entry import entry_fraction, inside_stays_inside
from canal_core.lone import lone_offsets


def converging_demos(n_demos: int = 6, n: int = 120) -> list[np.ndarray]:
    """Reaches along x whose start offsets (in y) fade out linearly over the first 60 % of the
    motion (a small spread in z, unrelated to the start offsets, keeps the canal open)."""
    s = np.linspace(0.0, 1.0, n)
    fade = np.clip(1.0 - s / 0.6, 0.0, 1.0)
    offsets = np.linspace(-0.1, 0.1, n_demos)
    return [np.column_stack([s, o * fade, 0.2 * s**2 + 0.003 * np.cos(2.5 * k)]) for k, o in enumerate(offsets)]


def test_inside_stays_inside_clamps_after_the_first_ratio_inside() -> None:
    ratios = np.array([3.0, 1.5, 0.9, 1.2, 0.5, 1.1])
    assert inside_stays_inside(ratios).tolist() == [3.0, 1.5, 0.9, 1.0, 0.5, 1.0]
    assert inside_stays_inside(np.array([2.0, 1.5])).tolist() == [2.0, 1.5]


def test_the_entry_length_is_where_the_demonstrations_offsets_half_faded() -> None:
    s = np.linspace(0.0, 1.0, 11)
    reach = np.ones(12)
    assert entry_fraction(s, 0.0, None, reach, 0.1) == 0.1  # nothing fades: the fixed blend
    kept = np.clip(1.2 - s, 0.0, 1.0)  # half faded at s = 0.7
    assert entry_fraction(s, 0.0, kept, reach, 0.1) == pytest.approx(0.7)
    narrowing = np.concatenate([[1.0], np.clip(1.0 - 2 * s, 0.1, 1.0)])  # half as wide at s = 0.3
    assert entry_fraction(s, 0.0, None, narrowing, 0.1) == pytest.approx(0.3)


def test_an_outside_start_enters_where_the_demonstrations_converge_and_stays_in() -> None:
    demos = converging_demos()
    canal = canal_core.fit(demos, n_samples=100)
    start = np.array([0.0, 0.25, 0.0])  # 2.5x the widest demo's offset
    learned = canal.reproduce_detailed(start)
    blended = canal.reproduce_detailed(start, entry=0.1)
    assert not learned.inside and learned.projected
    # The demos' offsets have half faded at 30 %: the path enters there, not after the fixed
    # tenth, and stays inside.
    inside = canal.contains(learned.positions)
    assert 0.2 * 100 < learned.entry_index <= 0.35 * 100
    assert inside[learned.entry_index:].all()
    assert blended.entry_index <= 0.12 * 100
    # It follows a demo started at the same offset (0.25 fade(s) in y) closer than the blend.
    s = learned.positions[:, 0]
    expected = 0.25 * np.clip(1.0 - s / 0.6, 0.0, 1.0)
    head = slice(0, learned.entry_index)
    assert np.abs(learned.positions[head, 1] - expected[head]).mean() < np.abs(
        blended.positions[head, 1] - expected[head]).mean()


def test_one_demonstrations_offset_is_a_translation_that_fades_over_the_rest() -> None:
    s = np.linspace(0.0, 1.0, 11)
    # Frames that turn a quarter turn about z over the motion: the offset does not turn with them.
    angle = np.linspace(0.0, np.pi / 2, 11)
    basis = np.stack([np.column_stack([-np.sin(angle), np.cos(angle), np.zeros(11)]),
                      np.tile([0.0, 0.0, 1.0], (11, 1))], axis=1)  # (11, 2, 3)
    d = np.array([0.0, 0.3, 0.1])
    v = lone_offsets(d, basis, s, 0.0)
    world = np.einsum("ka,kad->kd", v, basis)
    np.testing.assert_allclose(world[0], d)
    np.testing.assert_allclose(v[5], 0.5 * basis[5] @ d)  # half faded half way
    np.testing.assert_allclose(v[-1], 0.0)
    # From a start a fifth of the way in, it fades over the four fifths left.
    np.testing.assert_allclose(lone_offsets(d, basis[2:], s[2:], 0.2)[4], 0.5 * basis[6] @ d)


def test_a_start_off_a_one_demo_route_fades_over_the_motion_not_at_the_donors_pace() -> None:
    # Four demos over the top whose offsets converge within 15 % of the motion, one below: the
    # lone route borrows their narrowing sections, which say nothing about how a start off
    # its own way fades (L2).
    s = np.linspace(0.0, 1.0, 150)
    over = [np.column_stack([s, 0.3 * np.sin(np.pi * s) + 0.01 * k * np.clip(1 - s / 0.15, 0.2, 1.0),
                             np.full_like(s, 0.002 * k)]) for k in range(4)]
    under = [np.column_stack([s, -0.3 * np.sin(np.pi * s), np.zeros_like(s)])]
    routes = canal_core.routes.fit_routes(over + under, n_samples=100)
    lone = next(c for c in routes.every_canal if c.n_demos == 1)
    start = np.array([0.0, -0.04, 0.0])
    choice, rep = routes.reproduce_detailed(start)
    assert routes.canal_for(choice) is lone and not rep.inside
    offset = rep.positions[:, 1] + 0.3 * np.sin(np.pi * rep.positions[:, 0])
    fifth = offset.size // 5
    # Entered at the donors' pace, a fifth of the way in keeps about a tenth of the offset;
    # by (L2) most of it, and less than half half way (the translation fades linearly and its
    # part along the path's later tangents is time, not space).
    assert 0.6 < offset[fifth] / offset[0] < 0.9
    assert 0.1 < offset[offset.size // 2] / offset[0] < 0.5
    assert np.all(np.diff(np.abs(offset)) <= 1e-12)
    assert rep.entry_index > 0.4 * lone.n_sections
    assert lone.contains(rep.positions[rep.entry_index:]).all()
    steps = np.linalg.norm(np.diff(rep.positions, axis=0), axis=1)
    assert steps.max() <= 1.05 * np.linalg.norm(np.diff(lone.directrix, axis=0), axis=1).max()
    # A start inside stays inside, and a fixed entry asked for is the ratio rule's.
    inner = lone.directrix[0] + 0.5 * (lone.radii[0] / 0.04) * (start - lone.directrix[0])
    _, near = routes.reproduce_detailed(inner)
    assert near.inside and lone.contains(near.positions).all()
    _, fixed = routes.reproduce_detailed(start, entry=0.1)
    assert fixed.entry_index < 0.15 * lone.n_sections


def test_a_start_beyond_the_end_of_a_one_demo_route_ends_on_its_end() -> None:
    s = np.linspace(0.0, 1.0, 150)
    over = [np.column_stack([s, 0.3 * np.sin(np.pi * s) + 0.01 * k, np.full_like(s, 0.002 * k)]) for k in range(3)]
    under = [np.column_stack([s, -0.3 * np.sin(np.pi * s), np.zeros_like(s)])]
    routes = canal_core.routes.fit_routes(over + under, n_samples=100)
    lone = next(c for c in routes.every_canal if c.n_demos == 1)
    choice, rep = routes.reproduce_detailed(np.array([1.2, -0.1, 0.0]))
    assert routes.canal_for(choice) is lone
    np.testing.assert_allclose(rep.positions[-1], lone.directrix[-1], atol=1e-12)
    np.testing.assert_allclose(lone_offsets(np.array([0.2, -0.1, 0.0]), lone.basis[-1:], lone.arclength[-1:],
                                            float(lone.arclength[-1])), 0.0)


def test_an_inside_start_is_unchanged_by_the_learned_entry() -> None:
    canal = canal_core.fit(converging_demos(), n_samples=100)
    start = np.array([0.0, 0.05, 0.0])
    a = canal.reproduce_detailed(start)
    b = canal.reproduce_detailed(start, entry=0.1)
    assert a.inside
    np.testing.assert_array_equal(a.positions, b.positions)
    assert canal.contains(a.positions).all()


def _logged(times: np.ndarray) -> np.ndarray:
    """A smooth reach (speed from rest to rest) at the given times in [0, 1], shape (T, 3)."""
    u = 0.5 - 0.5 * np.cos(np.pi * times)
    return np.column_stack([np.sin(2 * u), u**2, 0.1 * u])


def test_a_logger_that_holds_a_slower_pose_source_is_a_steady_clock() -> None:
    # 100 Hz rows of a 40 Hz pose source: each pose is held for two or three rows.
    rows = np.arange(400) / 399.0
    held = _logged(np.floor(rows * 399.0 / 2.5) * 2.5 / 399.0)
    assert step_jitter(held) > STEADY_JITTER  # row to row, the steps jump from zero
    assert step_jitter(held, jitter_window(400)) < 0.2
    assert steady_index_clock([held, held * 1.1])
    assert chosen_clock([held, held * 1.05, held * 0.95], [None] * 3) == "index+arc"


def test_a_logger_that_writes_in_bursts_is_not_a_clock() -> None:
    # Blocks of ten rows, alternately 1 and 4 time units apart: the rate jumps fourfold from
    # one window of the alignment to the next.
    gaps = np.tile(np.repeat([1.0, 4.0], 10), 32)[:639]
    times = np.concatenate([[0.0], np.cumsum(gaps)])
    bursty = _logged(times / times[-1])
    steady = _logged(np.linspace(0.0, 1.0, 640))
    assert jitter_window(640) == 10
    assert step_jitter(bursty, jitter_window(640)) > 1.0
    assert step_jitter(steady, jitter_window(640)) < 0.1
    assert not steady_index_clock([steady, bursty])
    assert chosen_clock([steady, bursty, steady * 1.05], [None] * 3) == "arc"


def test_the_clock_follows_the_rhythm_of_the_demonstrations() -> None:
    u = np.linspace(0.0, 1.0, 300)
    path = np.column_stack([u, np.sin(np.pi * u), np.zeros_like(u)])
    same = [0.5 - 0.5 * np.cos(np.pi * u)] * 3  # one speed profile, three times
    warped = [u, u**1.6, 1.0 - (1.0 - u) ** 1.6]  # early fast / late fast
    stamps = [2.0 * u] * 3
    same_demos = [np.column_stack([np.interp(p, u, path[:, i]) for i in range(3)]) + 0.01 * k
                  for k, p in enumerate(same)]
    warped_demos = [np.column_stack([np.interp(p, u, path[:, i]) for i in range(3)]) + 0.01 * k
                    for k, p in enumerate(warped)]
    assert timing_spread(same_demos, stamps) < 0.01
    assert timing_spread(warped_demos, stamps) > 0.06
    assert chosen_clock(same_demos, stamps) == "time+arc"
    assert chosen_clock(warped_demos, stamps) == "arc"
    assert chosen_clock(same_demos, [None] * 3) == "index+arc"
    assert chosen_clock(warped_demos, [None] * 3) == "arc"
    assert chosen_clock(same_demos, [None] * 3, "index") == "index"
    assert chosen_clock(same_demos, stamps, "index") == "time"
    assert chosen_clock(same_demos, [None] * 3, "arc") == "arc"
    assert chosen_clock(same_demos, [None] * 3, "time") == "arc"  # nothing stamped
    assert chosen_clock(warped_demos, stamps, "time") == "time"


@pytest.mark.parametrize(("timestamps", "clock", "timed"), [(None, "index+arc", False), ("stamps", "time+arc", True)])
def test_the_fit_says_which_clock_it_used_and_an_untimed_model_has_no_seconds(timestamps, clock, timed) -> None:
    demos = converging_demos(n=150)
    stamps = [np.linspace(0.0, 3.0, 150)] * len(demos) if timestamps else None
    canal = canal_core.fit(demos, stamps, n_samples=60)
    assert canal.clock == clock
    assert (canal.section_times is not None) == timed
    assert (canal.reproduce_detailed(demos[0][0]).times is not None) == timed
    again = canal_core.Canal.from_dict(canal.to_dict())
    assert again.clock == clock
    assert canal_core.fit(demos, stamps, n_samples=60, timing="arc").clock == "arc"
    assert canal_core.fit(demos, stamps, n_samples=60, by_time=False).clock == "arc"
    assert canal_core.fit(demos, stamps, n_samples=60, by_time=True).clock == ("time" if timed else "arc")


def test_a_model_with_an_unknown_clock_is_refused() -> None:
    data = canal_core.fit(converging_demos(), n_samples=30).to_dict()
    data["clock"] = "sundial"
    with pytest.raises(canal_core.ModelFormatError, match="clock"):
        canal_core.Canal.from_dict(data)
    with pytest.raises(canal_core.InvalidInputError, match="timing"):
        canal_core.fit(converging_demos(), n_samples=30, timing="sundial")
