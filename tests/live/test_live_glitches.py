"""One glitch sample never moves a robot, over a real Zenoh session: a single pose (or a
short burst) far from the canal or far ahead is answered outside_canal with the way back in
from where the robot was, and the next good pose is answered as if it had never come."""

from __future__ import annotations

import contextlib
import threading
import time

import numpy as np
import pytest
from canal_client.live import PoseStreamer

from canal_core.tracker import SUSTAIN

pytestmark = pytest.mark.timeout(60)


def _answer(ps: PoseStreamer, x: np.ndarray):  # type: ignore[no-untyped-def]
    seq = ps.send(x.tolist())
    got = ps.wait_for(seq, 2.0)
    assert got is not None, "no answer"
    return got


@pytest.mark.parametrize("glitch,burst", [
    ("end", 1), ("far", 1), ("ahead", 1), ("end", 3), ("far", 3), ("mixed", 6)])
def test_a_glitch_between_good_poses_changes_nothing(live, glitch: str, burst: int) -> None:
    model = live.client.get("/skills/arc3/models/latest").json()
    c = np.array(model["directrix"])
    far = {"end": [2.0, 0.0, 0.0], "far": [5.0, 5.0, 5.0], "ahead": c[70].tolist()}
    with PoseStreamer("arc3", f"glitch-{glitch}-{burst}", endpoint=live.endpoint) as ps, \
            PoseStreamer("arc3", f"clean-{glitch}-{burst}", endpoint=live.endpoint,
                         session=ps.session) as clean:
        x = c[3] + 0.005
        for _ in range(8):  # both robots follow their targets from section 3
            a, b = _answer(ps, x), _answer(clean, x)
            assert a.target == b.target
            x = x + 0.5 * (np.array(a.target) - x)
        before = a
        for k in range(burst):
            which = glitch if glitch != "mixed" else ("end", "far")[k % 2]
            got = _answer(ps, np.array(far[which]))
            assert got.status == "outside_canal" and not got.done
            # the way back in from where the robot was, not a target at the canal's end
            assert got.section <= before.section + 1
            # the progress reached is kept (it read up to one section lower)
            assert before.progress <= got.progress <= before.progress + 0.02, (before, got)
            assert np.linalg.norm(np.array(got.target) - np.array(before.target)) < 0.05
        after, expected = _answer(ps, x), _answer(clean, x)
        assert after.status == "ok" and after.section == expected.section
        np.testing.assert_allclose(after.target, expected.target, rtol=1e-12)
        assert after.progress == expected.progress


def test_a_stream_whose_first_pose_is_a_glitch_starts_at_its_next_pose(live) -> None:
    c = np.array(live.client.get("/skills/arc3/models/latest").json()["directrix"])
    with PoseStreamer("arc3", "first-glitch", endpoint=live.endpoint) as ps:
        first = _answer(ps, np.array([2.0, 0.0, 0.0]))
        assert first.status == "outside_canal"
        got = _answer(ps, c[1] + 0.002)
        assert got.status == "ok" and got.section <= 2, got


def test_a_robot_moved_by_hand_is_followed_after_a_few_poses(live) -> None:
    c = np.array(live.client.get("/skills/arc3/models/latest").json()["directrix"])
    with PoseStreamer("arc3", "moved", endpoint=live.endpoint) as ps:
        x = c[3] + 0.002
        for _ in range(5):
            x = x + 0.5 * (np.array(_answer(ps, x).target) - x)
        there = 0.5 * (c[60] + c[61])
        answers = [_answer(ps, there) for _ in range(4)]
        assert [a.status for a in answers] == ["outside_canal"] * 3 + ["ok"]
        assert answers[-1].section == 60


def _follow(ps: PoseStreamer, x: np.ndarray, n: int):  # type: ignore[no-untyped-def]
    """``n`` poses of a robot that moves half-way to each target; (its position, last answer)."""
    answer = None
    for _ in range(n):
        answer = _answer(ps, x)
        x = x + 0.5 * (np.array(answer.target) - x)
    return x, answer


def _restart(ps: PoseStreamer, x: np.ndarray):  # type: ignore[no-untyped-def]
    got = ps.wait_for(ps.send(x.tolist(), restart=True), 2.0)
    assert got is not None, "no answer"
    return got


def test_a_glitch_sent_as_a_restart_never_sends_the_robot_to_the_canals_end(live) -> None:
    # A glitch pose at the canal's end with the restart flag re-located the stream there:
    # progress never goes back, so every next target was the canal's end.
    c = np.array(live.client.get("/skills/arc3/models/latest").json()["directrix"])
    with PoseStreamer("arc3", "restart-glitch", endpoint=live.endpoint) as ps:
        x, before = _follow(ps, c[3] + 0.005, 8)
        held = _restart(ps, c[-1])
        # no target: nothing moves, and the stream is as it was
        assert held.status == "restart_pending" and held.target is None, held
        assert not held.usable and "agree" in held.message
        # the stream's progress, as a held answer reports it: not reset to 0 by a glitch
        assert held.progress == pytest.approx(before.progress), (held, before)
        # the robot goes on where it is: the restart it asked for is made there, at once
        answers = [_answer(ps, x) for _ in range(3)]
        assert all(a.status == "ok" and not a.done for a in answers), answers
        assert all(a.section <= before.section + 1 for a in answers), answers
        assert all(a.progress < 0.2 for a in answers), answers


def test_a_restart_that_jumps_is_made_once_sustain_poses_agree(live) -> None:
    c = np.array(live.client.get("/skills/arc3/models/latest").json()["directrix"])
    with PoseStreamer("arc3", "restart-jump", endpoint=live.endpoint) as ps:
        x, before = _follow(ps, c[40] + 0.002, 5)
        start = c[5] + 0.002  # a new run, started at once from another place
        held = [_restart(ps, start)] + [_answer(ps, start) for _ in range(SUSTAIN - 2)]
        assert all(a.status == "restart_pending" and a.target is None for a in held), held
        got = _answer(ps, start)  # the SUSTAIN-th agreeing pose: the restart is made
        assert got.status == "ok" and got.section <= 6, got
        _, later = _follow(ps, start, 5)
        assert later.status == "ok" and later.section <= 10, later


def test_a_restart_near_the_pose_before_or_after_a_pause_is_made_at_once(live) -> None:
    c = np.array(live.client.get("/skills/arc3/models/latest").json()["directrix"])
    with PoseStreamer("arc3", "restart-near", endpoint=live.endpoint) as ps:
        x, _ = _follow(ps, c[5] + 0.002, 5)
        got = _restart(ps, x)
        assert got.status == "ok", got
        _follow(ps, c[40] + 0.002, 5)
        time.sleep(0.6)  # the robot was moved to another start while nothing was sent
        got = _restart(ps, c[5] + 0.002)
        assert got.status == "ok" and got.section <= 6, got


@contextlib.contextmanager
def _bridge_held(live, busy: PoseStreamer, at: list[float]):  # type: ignore[no-untyped-def]
    """The bridge's worker held on another robot's pose while the block runs: what the block
    sends queues up and is handled as one drain (a burst the bridge coalesces)."""
    bridge = live.client.app.state.bridge
    gate = threading.Event()
    original = bridge.path._handle

    def held(batch):  # type: ignore[no-untyped-def]
        gate.wait(5.0)
        return original(batch)

    bridge.path._handle = held
    try:
        busy.send(at)  # taken by the held worker: what follows queues behind it
        time.sleep(0.1)
        yield
        time.sleep(0.3)
    finally:
        gate.set()
        bridge.path._handle = original


@pytest.mark.parametrize(("encoding", "extra"), [
    ("json", None), ("binary", None),
    ("binary", "glitch restart"),  # a restart pose at the canal's end after the real one
    ("binary", "broken restart"),  # a pose no codec reads, flagged restart, after it
    ("binary", "2-D restart"),  # a pose of the wrong dimension, flagged restart, after it
])
def test_a_restart_in_a_coalesced_burst_is_made_not_dropped(
        live, encoding: str, extra: str | None) -> None:
    """A robot paused, was carried back to the start and sends its new run in a burst (a
    driver flushing its queue) while the bridge is busy: the burst is coalesced to its newest
    pose, and the restart its first pose asks for must still be made, and made as it would
    be pose by pose: a later restart pose that is a glitch, or no pose at all, changes
    nothing. Dropped with the coalesced poses, the newest was judged against the old run and
    answered with a target far along the canal, where the robot no longer is."""
    from canal_protocol import wire

    c = np.array(live.client.get("/skills/arc3/models/latest").json()["directrix"])
    name = f"burst-restart-{encoding}-{extra}".replace(" ", "-")
    with PoseStreamer("arc3", name, endpoint=live.endpoint, encoding=encoding) as ps, \
            PoseStreamer("arc3", f"busy-{name}", endpoint=live.endpoint,
                         session=ps.session) as busy:
        x, before = _follow(ps, c[60] + 0.002, 5)
        assert before.section >= 55, before
        time.sleep(0.6)  # the pause: the robot is carried back to the start
        start = c[5] + 0.002
        with _bridge_held(live, busy, c[30].tolist()):
            seqs = [ps.send(start.tolist(), restart=True)]
            seqs += [ps.send((start + 1e-5 * k).tolist()) for k in range(1, 5)]
            if extra == "glitch restart":
                ps.send(c[-1].tolist(), restart=True)
            elif extra == "broken restart":
                ps.send_raw(wire.encode_pose(0, start.tolist(), restart=True)[:20])
            elif extra == "2-D restart":
                ps.send_raw(wire.encode_pose(0, start[:2].tolist(), restart=True))
            seqs += [ps.send((start + 1e-5 * k).tolist()) for k in range(5, 30)]
        newest = ps.wait_for(seqs[-1], 2.0)
        later = [ps.wait_for(ps.send(start.tolist()), 2.0) for _ in range(3)]
    assert newest is not None and newest.coalesced >= 16, newest  # the burst was coalesced
    for got in [newest, *later]:
        assert got is not None and got.status == "ok" and got.section <= 7, got
        assert np.linalg.norm(np.array(got.target) - start) < 0.05, got


@pytest.mark.parametrize("every", [4, 3])
def test_glitch_restarts_spread_through_a_coalesced_burst_are_held(live, every: int) -> None:
    """Pose by pose, each good pose between glitches flagged restart cancels the pending
    one. Coalesced, those poses are gone: the glitches must not count as poses that agree,
    or the restart is made at the glitch, far from the robot."""
    c = np.array(live.client.get("/skills/arc3/models/latest").json()["directrix"])
    with PoseStreamer("arc3", f"spread-{every}", endpoint=live.endpoint) as ps, \
            PoseStreamer("arc3", f"busy-spread-{every}", endpoint=live.endpoint,
                         session=ps.session) as busy:
        x, before = _follow(ps, c[40] + 0.002, 5)
        with _bridge_held(live, busy, c[30].tolist()):
            seqs = [ps.send((c[-1] if k % every == every - 1 else x).tolist(),
                            restart=k % every == every - 1) for k in range(40)]
        newest = ps.wait_for(seqs[-1], 2.0)
        answers = [ps.latest()] + [ps.wait_for(ps.send(x.tolist()), 2.0) for _ in range(3)]
    assert newest is not None and newest.coalesced >= 16, newest  # the burst was coalesced
    for got in [newest, *answers]:
        assert got is not None
        assert got.target is None or np.linalg.norm(np.array(got.target) - x) < 0.05, got
    assert answers[-1].status == "ok" and answers[-1].section <= before.section + 2, answers


def _loop(client, name: str, angle: float, radius: float = 0.3,  # type: ignore[no-untyped-def]
          n: int = 120) -> np.ndarray:
    """The directrix of skill ``name``: four circles of radius about ``radius`` swept over
    ``angle`` radians (a canal that comes back near its start, or over itself), fitted once."""
    if client.get(f"/skills/{name}").status_code == 404:
        client.post("/skills", json={"name": name, "dim": 3})
        t = np.linspace(0.0, angle, n)
        for j in range(4):
            r = radius + 0.04 * (j - 1.5)
            demo = np.column_stack([r * np.cos(t), r * np.sin(t),
                                    0.002 * np.random.default_rng(j).standard_normal(n)])
            assert client.post(f"/skills/{name}/demonstrations",
                               json={"positions": demo.tolist()}).status_code == 201
        assert client.post(f"/skills/{name}/fit", json={"n_samples": 100}).status_code == 201
    return np.array(client.get(f"/skills/{name}/models/latest").json()["directrix"])


@pytest.mark.parametrize("turns", [1.9, 1.95])
def test_a_restart_glitch_near_the_robot_but_far_along_the_canal_is_held(live, turns) -> None:
    # On a canal that comes back near its start (a loop), a glitch at the end lay within 3
    # local radii of the robot at the start: the restart was made there, and every next
    # target was the canal's end. So was a glitch repeated once (a poller's stale sample),
    # and, closer still, one the plan took as a step but the restart re-located at the end.
    name = f"loop{int(turns * 100)}"
    c = _loop(live.client, name, turns * np.pi)
    with PoseStreamer(name, "looped", endpoint=live.endpoint) as ps:
        x, before = _follow(ps, c[3] + 0.002, 5)
        glitches = [ps.wait_for(ps.send(c[k].tolist(), restart=True), 2.0) for k in (-1, -4)]
        glitches.append(_answer(ps, c[-1]))  # repeated once, without the flag
        for a in glitches:
            assert a is not None and not a.done, a
            assert a.status == "restart_pending" or a.section <= before.section + 1, a
        answers = [_answer(ps, x) for _ in range(3)]
        assert all(a.status == "ok" and not a.done and a.section <= before.section + 1
                   for a in answers), answers


def test_a_restart_on_a_canal_narrow_at_its_goal_is_made_for_a_noisy_arm(live) -> None:
    # Poses of a robot that jumped were told to agree within 3 radii of the section it left:
    # after a run that ended where the canal is 0.3 mm wide, an arm back at the start with
    # 1 mm of sensor noise was answered restart_pending for as long as it streamed.
    client = live.client
    client.post("/skills", json={"name": "funnel", "dim": 3})
    s = np.linspace(0.0, 1.0, 100)[:, None]
    for j in range(4):
        side = np.array([0.0, np.cos(j * np.pi / 2), np.sin(j * np.pi / 2)]) * 0.03
        demo = s * np.array([0.6, 0.0, 0.0]) + (1.0 - s) * side
        assert client.post("/skills/funnel/demonstrations",
                           json={"positions": demo.tolist()}).status_code == 201
    assert client.post("/skills/funnel/fit", json={"n_samples": 100}).status_code == 201
    c = np.array(client.get("/skills/funnel/models/latest").json()["directrix"])
    rng = np.random.default_rng(0)
    with PoseStreamer("funnel", "noisy", endpoint=live.endpoint) as ps:
        x, last = _follow(ps, c[0], 400)
        assert last.done, last
        answers = [ps.wait_for(ps.send((c[3] + 1e-3 * rng.standard_normal(3)).tolist(),
                                       restart=k == 0), 2.0) for k in range(SUSTAIN + 2)]
        statuses = [a.status for a in answers]
        assert statuses[:SUSTAIN - 1] == ["restart_pending"] * (SUSTAIN - 1), statuses
        assert answers[SUSTAIN - 1].status == "ok" and answers[-1].section <= 6, answers


def test_a_new_run_on_a_loop_is_re_located_at_its_start(live) -> None:
    # On a canal that comes back near its start, the start of a new run lies within reach of
    # the end: the restart pose was taken as a step of the finished run, and every next
    # target stayed at the end while the robot went round the loop.
    c = _loop(live.client, "loop180", 1.8 * np.pi)
    with PoseStreamer("loop180", "rerun", endpoint=live.endpoint) as ps:
        _, last = _follow(ps, c[0], 400)
        assert last.done, last
        answers = [_restart(ps, c[0])] + [_answer(ps, c[k]) for k in range(1, 30)]
        assert not any(a.done for a in answers[1:]), answers
        assert answers[-1].status == "ok" and 25 <= answers[-1].section <= 33, answers[-1]


@pytest.mark.parametrize("restart_pose", ["own", "glitch"])
def test_a_robot_on_the_second_turn_of_a_loop_stays_on_it(live, restart_pose) -> None:
    # On a canal whose second turn lies over its first, the whole canal placed a pose of the
    # second turn on the first, more than 8 sections behind: a robot that sent a restart on
    # its own pose, or whose next pose followed a restart glitch, was sent back a turn.
    name = "turns175"
    c = _loop(live.client, name, 1.75 * 2 * np.pi, radius=0.36, n=160)
    with PoseStreamer(name, f"second-{restart_pose}", endpoint=live.endpoint) as ps:
        answers = [_answer(ps, c[k]) for k in range(83)]
        assert answers[-1].section >= 80, answers[-1]
        sent = c[82] + 0.002 if restart_pose == "own" else np.array([5.0, 5.0, 5.0])
        _restart(ps, sent)
        after = [_answer(ps, c[k]) for k in range(83, 88)]
        assert all(a.section >= 80 and not a.done for a in after), after
