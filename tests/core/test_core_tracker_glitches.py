"""One glitch sample never moves a robot: a live pose far from the canal or too far ahead
(a sensor spike, one sample in a wrong frame, a jump across the canal) is answered from the
stream's last plausible state and leaves it as it was, in every tracker path (the scalar
step, the numpy batch, the bank's numpy pass and the compiled kernel); a sustained
displacement (a real push) is still followed."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
from core_data import sleeve_demos

import canal_core
from canal_core.tracker import (
    FAR_ETA,
    MAX_ADVANCE,
    SUSTAIN,
    Tracker,
    TrackerState,
    TrackerTarget,
)
from canal_core.tracker_bank import TrackerBank
from canal_core.tracker_batch import tracker_steps
from canal_core.tracker_kernel import compile_step_rows

Step = Callable[[np.ndarray], TrackerTarget]
PATHS = ["scalar", "batch", "bank", "compiled"]


@pytest.fixture(scope="module")
def tube() -> canal_core.Canal:
    """A straight canal along x from 0 to 1, radius 0.05, 60 sections."""
    x = np.linspace(0.0, 1.0, 120)
    demos = [np.column_stack([x, 0.05 * np.cos(a) + 0 * x, 0.05 * np.sin(a) + 0 * x])
             for a in np.linspace(0.0, 2 * np.pi, 6, endpoint=False)]
    return canal_core.fit(demos, n_samples=60)


@pytest.fixture(scope="module")
def helix() -> canal_core.Canal:
    """Two turns of a thin helix: the next turn passes 0.8 below each point."""
    return canal_core.fit(sleeve_demos(), n_samples=120)


def stream(canal: canal_core.Canal, path: str, lookahead: int = 2) -> Step:
    """One stream's step through ``path``; the batch paths carry a second stream that sits
    at the canal's start, so every call is a vectorised pass of two rows."""
    geometry = canal.tracker(lookahead).geometry
    if path == "scalar":
        return Tracker(geometry, lookahead).step
    still = canal.directrix[0] + 0.3 * float(canal.radii[0]) * canal.normals[0]
    if path == "batch":
        states = [TrackerState(), TrackerState()]

        def batch_step(x: np.ndarray) -> TrackerTarget:
            targets, new = tracker_steps(geometry, states, np.array([x, still]), lookahead)
            states[:] = new
            return targets[0]
        return batch_step
    if path == "compiled":
        assert compile_step_rows() is not None
    bank = TrackerBank(geometry, lookahead, compiled=path == "compiled")
    slots = [bank.add(), bank.add()]

    def bank_step(x: np.ndarray) -> TrackerTarget:
        got = bank.step(slots, np.array([x, still]))
        return TrackerTarget(got.target[0], float(got.progress[0]), float(got.eta[0]),
                             int(got.section_index[0]), bool(got.inside[0]), bool(got.done[0]))
    return bank_step


def walk(canal: canal_core.Canal, step: Step, start: int, poses: int) -> tuple[np.ndarray, TrackerTarget]:
    """Follow the targets from near section ``start`` for ``poses`` poses; the last position
    and answer."""
    x = canal.directrix[start] + 0.2 * float(canal.radii[start]) * canal.normals[start]
    answer = step(x)
    for _ in range(poses):
        x = x + 0.3 * (answer.target - x)
        answer = step(x)
    return x, answer


def same_answer(got: TrackerTarget, expected: TrackerTarget) -> None:
    assert (got.section_index, got.inside, got.done) == (
        expected.section_index, expected.inside, expected.done)
    np.testing.assert_allclose(got.target, expected.target, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(got.progress, expected.progress, rtol=1e-9, atol=1e-12)


def glitches(canal: canal_core.Canal) -> dict[str, np.ndarray]:
    c = canal.directrix
    return {
        "beyond the end": np.array([2.0, 0.0, 0.0]),
        "far off": np.array([5.0, 5.0, 5.0]),
        "overflowing": np.full(3, 1e308),
        "before the start": np.array([-1.0, 0.0, 0.0]),
        "ahead inside": c[40] + 0.01 * canal.normals[40],  # 30 sections on, in the canal
        "beside": c[10] + 0.5 * canal.normals[10],  # 10 radii out, beside the robot
    }


@pytest.mark.parametrize("path", PATHS)
@pytest.mark.parametrize("glitch", ["beyond the end", "far off", "overflowing",
                                    "before the start", "ahead inside", "beside"])
@pytest.mark.parametrize("burst", [1, SUSTAIN - 1])
def test_a_short_burst_of_glitch_poses_changes_nothing(
        tube: canal_core.Canal, path: str, glitch: str, burst: int) -> None:
    """The next good pose gets exactly the answer it gets with no glitch before it; the
    glitch poses are answered outside, from the section reached, on the plan."""
    clean, glitched = stream(tube, path), stream(tube, path)
    x, before = walk(tube, clean, 8, 12)
    walk(tube, glitched, 8, 12)
    bad = glitches(tube)[glitch]
    with np.errstate(all="ignore"):
        answers = [glitched(bad) for _ in range(burst)]
    for a in answers:
        assert not a.inside and not a.done
        assert a.section_index <= before.section_index + 1
        np.testing.assert_allclose(a.target, before.target, atol=0.3 * tube.radii.max())
    same_answer(glitched(x), clean(x))


@pytest.mark.parametrize("path", PATHS)
def test_spikes_at_changing_places_never_add_up_to_a_push(tube: canal_core.Canal,
                                                          path: str) -> None:
    """Suspect poses count as a push only when they agree on where the robot is: spikes
    alternating between the end and far away never move the robot, however many."""
    clean, glitched = stream(tube, path), stream(tube, path)
    x, before = walk(tube, clean, 5, 10)
    walk(tube, glitched, 5, 10)
    with np.errstate(all="ignore"):
        for k in range(3 * SUSTAIN):
            a = glitched(np.array([2.0, 0.0, 0.0]) if k % 2 else np.array([-3.0, 5.0, 5.0]))
            assert a.section_index <= before.section_index + 1 and not a.inside
    same_answer(glitched(x), clean(x))


@pytest.mark.parametrize("path", PATHS)
def test_a_sustained_jump_is_followed_at_its_sustain_th_pose(tube: canal_core.Canal,
                                                             path: str) -> None:
    """A robot moved by hand 30 sections on (and a push far beside it) is followed once
    SUSTAIN consecutive poses agree, as if the last of them had come first."""
    step = stream(tube, path)
    walk(tube, step, 8, 12)
    there = tube.directrix[40] + 0.01 * tube.normals[40] + 0.3 * (
        tube.directrix[41] - tube.directrix[40])
    answers = [step(there) for _ in range(SUSTAIN)]
    assert all(a.section_index < 20 for a in answers[:-1])
    assert answers[-1].section_index == 40 and answers[-1].inside
    # and progress stays there: a pose back near the old place is outside, answered there
    back = step(tube.directrix[12])
    assert back.section_index >= 39 and not back.inside


@pytest.mark.parametrize("path", PATHS)
def test_a_coarse_stream_moved_faster_than_the_rule_allows_is_followed(
        tube: canal_core.Canal, path: str) -> None:
    """A slow stream (a 10 Hz topic) of an arm moved by hand: every pose is more than
    MAX_ADVANCE sections past the one before and more than FAR_ETA radii from it, but each
    lies in the canal ahead of the last. The SUSTAIN-th such pose is followed, and so is
    every next one: the stream does not stay answered from where it was."""
    step = stream(tube, path)
    _, before = walk(tube, step, 1, 3)
    spacing = float(np.linalg.norm(tube.directrix[1] - tube.directrix[0]))
    stride = MAX_ADVANCE + 2
    assert stride * spacing > FAR_ETA * float(tube.radii.max())  # too far apart to agree by distance
    sections = [before.section_index + stride * (k + 1) for k in range(SUSTAIN + 1)]
    assert sections[-1] < len(tube.directrix) - 2
    answers = [step(tube.directrix[s] + 0.3 * float(tube.radii[s]) * tube.normals[s])
               for s in sections]
    assert all(a.section_index <= before.section_index + 1 for a in answers[:SUSTAIN - 1])
    for a, s in zip(answers[SUSTAIN - 1:], sections[SUSTAIN - 1:], strict=True):
        assert s - 1 <= a.section_index <= s  # a pose on plane s lies between s - 1 and s
    assert all(a.inside for a in answers[SUSTAIN - 1:])


@pytest.mark.parametrize("path", PATHS)
def test_poses_in_the_canal_that_jump_back_and_forth_never_add_up_to_a_push(
        tube: canal_core.Canal, path: str) -> None:
    """Suspect poses in the canal count as a moved arm only while each is ahead of the
    last: spikes alternating between two places ahead never move the robot."""
    clean, glitched = stream(tube, path), stream(tube, path)
    x, before = walk(tube, clean, 5, 10)
    walk(tube, glitched, 5, 10)
    far, near = tube.directrix[50], tube.directrix[30]
    for k in range(3 * SUSTAIN):
        a = glitched(far if k % 2 else near)
        assert a.section_index <= before.section_index + 1 and not a.inside
    same_answer(glitched(x), clean(x))


@pytest.mark.parametrize("path", PATHS)
def test_a_robot_pushed_far_out_beside_its_section_is_followed(tube: canal_core.Canal,
                                                              path: str) -> None:
    step = stream(tube, path)
    _, before = walk(tube, step, 8, 12)
    out = tube.directrix[12] + 2.0 * FAR_ETA * float(tube.radii[12]) * tube.normals[12]
    answers = [step(out + 1e-4 * k * tube.normals[12]) for k in range(SUSTAIN)]
    assert [a.inside for a in answers] == [False] * SUSTAIN
    # held on the plan, then replanned toward the robot (the way back in from where it is)
    np.testing.assert_allclose(answers[0].target, before.target, atol=0.3 * tube.radii.max())
    toward = (answers[-1].target - tube.directrix[answers[-1].section_index + 2]) @ tube.normals[12]
    assert toward > 0.5 * float(tube.radii[12])


@pytest.mark.parametrize("path", PATHS)
def test_a_glitch_after_a_followed_displacement_off_the_canal_is_held(
        tube: canal_core.Canal, path: str) -> None:
    """A person holds the arm well off the canal (followed after SUSTAIN poses); one glitch
    on the canal near its end was then taken as the arm moved on along the canal (ahead of
    the held pose), and the target went to the end. A pose that agrees by running ahead
    must also stay within FAR_ETA radii of the line the last one ran along."""
    step = stream(tube, path)
    walk(tube, step, 8, 12)
    out = tube.directrix[12] + 2.0 * FAR_ETA * float(tube.radii[12]) * tube.normals[12]
    held = [step(out + 1e-4 * k * tube.normals[12]) for k in range(SUSTAIN + 2)]
    assert held[-1].section_index <= 13
    glitch = step(tube.directrix[-1])
    assert not glitch.done and not glitch.inside, glitch
    assert glitch.section_index <= held[-1].section_index + 2, glitch
    np.testing.assert_allclose(glitch.target, held[-1].target, atol=0.3 * tube.radii.max())
    again = step(out)  # the arm, still held there
    assert again.section_index <= held[-1].section_index + 2 and not again.done


@pytest.mark.parametrize("path", PATHS)
def test_a_glitch_far_ahead_after_stale_poses_behind_is_held(tube: canal_core.Canal,
                                                             path: str) -> None:
    """Stale poses replayed from behind (an old log, a second publisher on the key) are
    followed as a displacement; one glitch at the canal's end after them ran ahead of the
    last and was taken. A pose agrees by running ahead only up to MAX_ONWARD sections ahead
    of the one before: an arm moved faster than that on a slow stream is followed once its
    poses agree by distance."""
    step = stream(tube, path)
    walk(tube, step, 20, 12)
    stale = [step(tube.directrix[8] + 0.01 * tube.normals[8]) for _ in range(SUSTAIN + 1)]
    assert not stale[-1].done
    glitch = step(tube.directrix[-1])
    assert not glitch.done and not glitch.inside and glitch.section_index < 30, glitch


@pytest.mark.parametrize("path", PATHS)
@pytest.mark.parametrize("glitch", ["beyond the end", "far off", "overflowing"])
def test_a_stream_whose_first_pose_is_a_glitch_starts_where_its_next_pose_is(
        tube: canal_core.Canal, path: str, glitch: str) -> None:
    """No plausible state yet: the glitch gets the entry the canal gives it (outside) and
    the stream stays unplaced; the next pose at the start is answered at the start."""
    step, clean = stream(tube, path), stream(tube, path)
    with np.errstate(all="ignore"):
        first = step(glitches(tube)[glitch])
    assert not first.inside
    start = tube.directrix[1] + 0.3 * float(tube.radii[1]) * tube.normals[1]
    same_answer(step(start), clean(start))
    assert clean(start).section_index <= 1


@pytest.mark.parametrize("path", PATHS)
def test_a_pose_on_the_helix_next_turn_does_not_skip_the_turn(helix: canal_core.Canal,
                                                               path: str) -> None:
    """A jump across the canal: one pose 0.8 below the robot lies in the canal a whole
    turn on; the robot's next good pose continues where it was."""
    clean, glitched = stream(helix, path), stream(helix, path)
    x, before = walk(helix, clean, 10, 10)
    walk(helix, glitched, 10, 10)
    turn = helix.directrix[before.section_index + 60]
    with np.errstate(all="ignore"):
        a = glitched(turn)
    assert not a.inside and a.section_index <= before.section_index + 1
    same_answer(glitched(x), clean(x))


def test_the_rule_s_constants_are_what_the_docs_say() -> None:
    """docs/live.md names these numbers: a change here must change the page."""
    from pathlib import Path

    page = (Path(__file__).parents[2] / "docs" / "live.md").read_text()
    for name, value in (("MAX_ADVANCE", MAX_ADVANCE), ("FAR_ETA", FAR_ETA), ("SUSTAIN", SUSTAIN)):
        assert f"`{name}` = {value:g}" in page


@pytest.mark.parametrize("path", ["scalar", "bank"])
@pytest.mark.parametrize("glitch", ["beyond the end", "far off", "ahead inside", "beside"])
def test_a_glitch_changes_nothing_on_ellipse_sections(path: str, glitch: str) -> None:
    """Sections whose reach depends on the direction (the held answer looks its reach up
    along the kept plan): the same rule."""
    x = np.linspace(0.0, 1.0, 120)
    demos = [np.column_stack([x, 0.08 * np.cos(a) + 0 * x, 0.04 * np.sin(a) + 0 * x])
             for a in np.linspace(0.0, 2 * np.pi, 8, endpoint=False)]
    canal = canal_core.fit(demos, n_samples=60, cross_section="ellipse")
    clean, glitched = stream(canal, path), stream(canal, path)
    x0, before = walk(canal, clean, 8, 12)
    walk(canal, glitched, 8, 12)
    with np.errstate(all="ignore"):
        a = glitched(glitches(canal)[glitch])
    assert not a.inside and a.section_index <= before.section_index + 1
    same_answer(glitched(x0), clean(x0))


def test_poses_agree_within_three_radii_of_the_widest_section(tube: canal_core.Canal) -> None:
    from canal_core.tracker import poses_agree

    g = tube.tracker_geometry()
    r = float(tube.radii.max())
    here = tube.directrix[10]
    assert poses_agree(g, here + [0.0, 0.9 * FAR_ETA * r, 0.0], here)
    assert not poses_agree(g, here + [0.0, 1.1 * FAR_ETA * r, 0.0], here)
    assert not poses_agree(g, tube.directrix[-1], here)  # a jump along the canal


def test_located_section_is_where_the_whole_canal_places_a_point(tube: canal_core.Canal) -> None:
    from canal_core.tracker import located_section

    g = tube.tracker_geometry()
    for k in (0, 17, 40):
        assert abs(located_section(g, 0.5 * (tube.directrix[k] + tube.directrix[k + 1])) - k) <= 1
