"""Reactive tracker, metrics, alignment and preprocessing on known inputs."""

from __future__ import annotations

import numpy as np
import pytest
from core_data import sleeve_demos

import canal_core
from canal_core import datasets, metrics
from canal_core.alignment import dtw_aligned_demonstrations, normalised_arc_length
from canal_core.preprocess import cleaned_demonstration
from canal_core.warping import dtw_path


def simulate(canal: canal_core.Canal, start: np.ndarray, steps: int = 2000, gain: float = 0.5,
             push_at: int | None = None, push: np.ndarray | None = None) -> tuple[np.ndarray, list]:
    tracker = canal.tracker(lookahead=2)
    x = start.copy()
    path, answers = [x.copy()], []
    for k in range(steps):
        answer = tracker.step(x)
        answers.append(answer)
        if answer.done:
            break
        x = x + gain * (answer.target - x)
        if push_at is not None and k == push_at:
            x = x + push
        path.append(x.copy())
    return np.array(path), answers


def test_tracker_reaches_the_end_inside_with_monotone_progress() -> None:
    canal = canal_core.fit(datasets.task_one(), cross_section="ellipse")
    start = np.array([0.0, 0.1, -0.05])
    path, answers = simulate(canal, start)
    assert answers[-1].done
    progress = np.array([a.progress for a in answers])
    assert (np.diff(progress) >= -1e-12).all()
    assert progress[-1] == 1.0
    assert all(a.inside for a in answers[1:])
    middle = path[np.argmin(np.abs(path[:, 0] - 0.5))]
    assert np.hypot(middle[1], middle[2]) < 0.011  # through the narrow middle


def wide_turn_demos(spread: float = 0.3, turn_radius: float = 0.1) -> list[np.ndarray]:
    """Demonstrations a canal wider than its turn is tight holds: neighbouring section planes
    cross inside the canal (as on real pressing and pushing demos spread over 20 cm)."""
    th = np.linspace(0.0, np.pi / 2.0, 200)
    demos = []
    for a, b in [(1, 0.3), (-1, 0.2), (0.3, -1), (-0.2, 1), (0.0, 0.0), (0.7, 0.7)]:
        r = turn_radius + 0.5 * spread * a
        demos.append(np.column_stack([r * np.cos(th), r * np.sin(th), spread * b + 0.05 * th]))
    return demos


def wide_turn_starts(canal: canal_core.Canal) -> np.ndarray:
    starts = []
    for k in (0, 20, 60):
        for angle in np.linspace(0.0, 2.0 * np.pi, 8, endpoint=False):
            side = np.cos(angle) * canal.normals[k] + np.sin(angle) * canal.binormals[k]
            starts += [canal.directrix[k] + eta * canal.radii[k] * side for eta in (0.3, 0.6, 0.85)]
    return np.array(starts)


@pytest.mark.parametrize("path", ["scalar", "numpy", "compiled"])
def test_a_robot_on_its_targets_reaches_the_end_where_section_planes_cross(path: str) -> None:
    # Where planes cross inside the canal, a robot on its target could lie behind a plane
    # between it and the section it was located at: the target stayed where it was and the
    # robot stood still on it (6 of these 72 starts), or went back and forth between two
    # targets. On real demonstrations by seven people, a robot following its targets from
    # each demo's start reached the end from 11 of 146.
    from canal_core.tracker_bank import TrackerBank
    from canal_core.tracker_kernel import compile_step_rows

    canal = canal_core.fit(wide_turn_demos(), n_samples=150)
    starts = wide_turn_starts(canal)
    if path == "scalar":
        done = [simulate(canal, start, gain=0.3)[1][-1].done for start in starts]
    else:
        if path == "compiled":
            assert compile_step_rows() is not None, "numba is a dependency of the dev install"
        bank = TrackerBank(canal.tracker(lookahead=2).geometry, lookahead=2,
                           compiled=path == "compiled")
        slots = [bank.add() for _ in starts]
        for slot, start in zip(slots, starts, strict=True):
            bank.reset(slot, int(canal.reproduce_detailed(start).section_index))
        x = starts.copy()
        finished = np.zeros(len(starts), dtype=bool)
        for _ in range(2000):
            batch = bank.step(slots, x)
            finished |= batch.done
            if finished.all():
                break
            x = x + 0.3 * (batch.target - x)
        done = finished.tolist()
    assert sum(done) == len(starts), f"{len(starts) - sum(done)} of {len(starts)} stood still"


def test_tracker_recovers_from_a_push() -> None:
    canal = canal_core.fit(sleeve_demos(), n_samples=200)
    start = canal.directrix[0] + 0.02 * canal.normals[0]
    path, answers = simulate(canal, start, push_at=100, push=0.03 * canal.binormals[60])
    assert answers[-1].done
    # After the push the robot is carried back inside within a few steps.
    assert all(a.inside for a in answers[110:])


def test_tracker_does_not_jump_back_on_a_self_approaching_curve() -> None:
    # A hairpin: the return leg passes 4 cm from the outgoing one.
    s = np.linspace(0, 1, 200)
    leg = np.column_stack([np.sin(np.pi * s) * 0.3, 0.02 * np.cos(np.pi * s), 0 * s])
    demos = [leg + [0, 0, dz] for dz in (-0.005, 0.005)] + [leg * [1, 1.1, 1]]
    canal = canal_core.fit(demos, n_samples=200)
    tracker = canal.tracker()
    for x in canal.directrix[:150]:
        answer = tracker.step(x)
    reached = answer.section_index
    # A point on the outgoing leg again (near the return leg) must not move progress back.
    answer = tracker.step(canal.directrix[20])
    assert answer.section_index >= reached - 1
    tracker.reset()
    assert tracker.step(canal.directrix[5]).section_index <= 6


def test_tracker_in_two_dimensions() -> None:
    x = np.linspace(0, 1, 80)
    demos = [np.column_stack([x, 0.3 * np.sin(np.pi * x) + d * (1.2 - x)]) for d in (-0.05, 0.02, 0.1)]
    canal = canal_core.fit(demos, n_samples=80)
    _, answers = simulate(canal, canal.directrix[0] + [0.0, 0.01])
    assert answers[-1].done and all(a.inside for a in answers[1:])


def test_dtw_and_frechet_on_known_curves() -> None:
    a = np.column_stack([np.arange(5.0), np.zeros(5)])
    b = a + [0.0, 1.0]
    assert metrics.discrete_frechet_distance(a, b) == pytest.approx(1.0)
    assert metrics.dtw_distance(a, b) == pytest.approx(5.0)
    # A time-warped copy has zero DTW distance, and the path undoes the warp.
    slow = np.repeat(a, 2, axis=0)
    assert metrics.dtw_distance(a, slow) == pytest.approx(0.0)
    ia, ib = dtw_path(a, slow)
    np.testing.assert_array_equal(a[ia], slow[ib])
    assert metrics.rmse(a, b) == pytest.approx(1.0)
    assert metrics.path_length(a) == pytest.approx(4.0)
    assert metrics.jerk(a) == 0.0
    assert metrics.jerk(np.column_stack([np.arange(6.0) ** 3, np.zeros(6)])) == pytest.approx(36.0)


def test_containment_metric() -> None:
    canal = canal_core.fit(datasets.task_one())
    assert metrics.containment(canal, canal.directrix) == 1.0
    assert metrics.containment(canal, canal.directrix + [0, 1.0, 0]) == 0.0


def test_dtw_alignment_matches_speed_variations() -> None:
    # The same path walked at different speeds (by time): DTW alignment recovers it.
    u = np.linspace(0, 1, 300)
    path = lambda s: np.column_stack([s, np.sin(2 * np.pi * s) * 0.2, 0 * s])  # noqa: E731
    demos = [path(u), path(u**1.5), path(u**0.7)]
    times = [u, u, u]
    by_time = canal_core.alignment.resampled_demonstrations(demos, times, 100)
    by_dtw = dtw_aligned_demonstrations(demos, times, 100)
    spread_time = np.ptp(by_time[:, :, 0], axis=0).max()
    spread_dtw = np.ptp(by_dtw[:, :, 0], axis=0).max()
    assert spread_dtw < 0.35 * spread_time


def test_preprocessing_drops_repeats_and_still_ends() -> None:
    moving = np.column_stack([np.linspace(0, 1, 50), np.zeros(50), np.zeros(50)])
    raw = np.vstack([np.repeat(moving[:1], 30, axis=0), np.repeat(moving, 3, axis=0), np.repeat(moving[-1:], 40, axis=0)])
    cleaned, _ = cleaned_demonstration(raw)
    np.testing.assert_array_equal(cleaned, moving)
    s = normalised_arc_length(cleaned)
    assert s[0] == 0.0 and s[-1] == 1.0 and (np.diff(s) > 0).all()


def helix_canal() -> canal_core.Canal:
    # Two turns, sections spaced about one canal radius apart: corner cutting is large.
    rng = np.random.default_rng(0)
    return canal_core.fit([datasets.helix(200) + 0.03 * rng.standard_normal(3) for _ in range(5)])


def test_tracker_is_not_done_in_the_last_planes_half_space_on_an_earlier_turn() -> None:
    canal = helix_canal()
    # Section 120 is most of a turn before the end, yet in front of the last plane.
    tracker = canal.tracker(lookahead=2)
    tracker.reset(120)
    answer = tracker.step(canal.directrix[120])
    assert canal.tangents[-1] @ (canal.directrix[120] - canal.directrix[-1]) > 0.5
    assert not answer.done and answer.progress < 0.7


@pytest.mark.parametrize("gain", [0.2, 0.5])
def test_a_lagging_robot_keeps_its_ratio_on_a_tight_helix(gain: float) -> None:
    # Replanning from the live position at every step let corner cutting drift a robot
    # started at eta ~0.1 out of this canal within 25 sections.
    canal = helix_canal()
    for fraction in (0.1, 0.5):
        start = canal.directrix[55] + fraction * canal.radii[55] * canal.normals[55]
        tracker = canal.tracker(lookahead=2)
        tracker.reset(55)
        x, answers = start, []
        for _ in range(2000):
            answers.append(tracker.step(x))
            if answers[-1].done:
                break
            x = x + gain * (answers[-1].target - x)
        assert answers[-1].done and answers[-1].section_index >= canal.n_sections - 2
        assert all(a.inside for a in answers)
        assert abs(answers[-1].eta - answers[0].eta) < 0.1


def test_a_push_replans_from_where_the_robot_is() -> None:
    canal = canal_core.fit(sleeve_demos(), n_samples=200)
    tracker = canal.tracker(lookahead=2)
    x = canal.directrix[0] + 0.2 * canal.radii[0] * canal.normals[0]
    for _ in range(60):
        x = x + 0.5 * (tracker.step(x).target - x)
    planned = tracker.state.eta
    # a small nudge (well under the replan tolerance) is pulled back to the plan...
    tracker.step(x + 0.02 * canal.radii[60] * canal.normals[60])
    assert tracker.state.eta == planned
    # ...a real push becomes the new plan
    pushed = x + 0.6 * canal.radii[60] * canal.binormals[60]
    answer = tracker.step(pushed)
    assert tracker.state.eta != planned and abs(tracker.state.eta - min(answer.eta, 0.9)) < 1e-12


def test_a_robot_on_its_final_target_is_inside_on_every_tracker_path() -> None:
    """The last target lies on the last plane up to rounding; a robot that reached it a hair
    past that plane was answered done but outside (the end's half-space is outside), in the
    scalar step, the numpy batch and the compiled kernel alike."""
    from canal_core.tracker_bank import TrackerBank
    from canal_core.tracker_kernel import compile_step_rows

    canal = canal_core.fit(sleeve_demos(), n_samples=200)
    tolerance = canal.tracker_geometry().done_tolerance
    end = canal.directrix[-1] + 0.3 * canal.radii[-1] * canal.normals[-1]
    poses = [end - 0.5 * tolerance * canal.tangents[-1], end + 0.5 * tolerance * canal.tangents[-1]]
    compile_step_rows()
    for pose in poses:
        walks = {"scalar": canal.tracker(), "numpy": TrackerBank(canal.tracker_geometry(), 1, compiled=False),
                 "compiled": TrackerBank(canal.tracker_geometry(), 1, compiled=True)}
        for name, walk in walks.items():
            if isinstance(walk, TrackerBank):
                slot = walk.add()
                for point in canal.directrix[:-1:4]:
                    walk.step([slot], point[None, :])
                answer = walk.step([slot], pose[None, :])
                inside, done = bool(answer.inside[0]), bool(answer.done[0])
            else:
                for point in canal.directrix[:-1:4]:
                    walk.step(point)
                step = walk.step(pose)
                inside, done = step.inside, step.done
            assert done and inside, name
