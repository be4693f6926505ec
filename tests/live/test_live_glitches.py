"""One glitch sample never moves a robot, over a real Zenoh session: a single pose (or a
short burst) far from the canal or far ahead is answered outside_canal with the way back in
from where the robot was, and the next good pose is answered as if it had never come."""

from __future__ import annotations

import numpy as np
import pytest
from canal_client.live import PoseStreamer

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
