"""Live targets around a scene (the tracker bank's obstacle pass), driven by a lagging robot."""

from __future__ import annotations

import numpy as np
import pytest
from canal_testing import arc_demo
from core_data import ring_canal, tube_demos

import canal_core
from canal_core.obstacles import free_distances, rotation_parameters, scene_from_list
from canal_core.tracker_bank import TrackerBank
from canal_core.tracker_obstacles import BLOCKED, DETOUR, IN_OBSTACLE, OK, scene_tables


@pytest.fixture(scope="module")
def tube() -> canal_core.Canal:
    demos = tube_demos(radius=0.5, n_demos=6, n_points=80)
    for j, d in enumerate(demos):
        d[:, 1] += 0.08 * np.sin(2.0 * d[:, 0] + j)
        d[:, 2] += 0.08 * np.cos(2.5 * d[:, 0] + 2 * j)
    return canal_core.fit(demos, n_samples=120)


def drive(canal: canal_core.Canal, items: list[dict[str, object]], x: np.ndarray, steps: int = 400,
          robots: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``robots`` first-order robots from around ``x``, stepped together: poses, targets,
    statuses (steps, robots, ...) and whether each finished."""
    bank = TrackerBank(canal.tracker_geometry(), 2, compiled=False)
    bank.scene = scene_tables(bank.geometry, scene_from_list(items, 3), canal.section_steps)
    slots = [bank.add(0) for _ in range(robots)]
    pos = x + np.linspace(-0.2, 0.2, robots)[:, None] * float(canal.radii[0]) * canal.normals[0]
    poses, targets, statuses = [], [], []
    done = np.zeros(robots, dtype=bool)
    for _ in range(steps):
        rows = bank.step_packed(slots, pos)
        status = bank.avoid_packed(rows, pos)
        assert status is not None
        poses.append(pos.copy())
        targets.append(rows[:, :3].copy())
        statuses.append(status)
        done |= rows[:, 7] != 0.0
        if done.all():
            break
        pos = pos + 0.6 * (rows[:, :3] - pos)
    return np.array(poses), np.array(targets), np.array(statuses), done


def test_robots_swerve_around_a_ball_on_their_way_and_finish() -> None:
    arc = canal_core.fit([arc_demo(j, 60, spread=0.03) for j in range(4)], n_samples=100)
    k = arc.n_sections // 2
    ball = {"kind": "sphere", "center": arc.directrix[k].tolist(), "radius": 0.5 * float(arc.radii[k]),
            "clearance": 0.002}
    poses, targets, statuses, done = drive(arc, [ball], arc.directrix[0], robots=3)
    scene = scene_from_list([ball], 3)
    assert done.all()
    assert (statuses == DETOUR).any() and not (statuses == BLOCKED).any()
    assert free_distances(poses.reshape(-1, 3), scene).min() >= 0.0
    assert free_distances(targets.reshape(-1, 3), scene).min() >= 0.0


def test_a_passage_the_reproduction_takes_stays_open_live_where_one_demo_stepped_far_elsewhere() -> None:
    # One demonstration sets off from far aside: the demonstrations' largest step (at the
    # head) is ten times their step anywhere else. The live margin and reach are the
    # demonstrations' own steps around each section, so a ball that leaves a passage
    # narrower than half that largest step does not close the canal to a live robot.
    demos = tube_demos(radius=0.5, n_demos=6, n_points=80)
    for j, d in enumerate(demos):
        d[:, 1] += 0.08 * np.sin(2.0 * d[:, 0] + j)
        d[:, 2] += 0.08 * np.cos(2.5 * d[:, 0] + 2 * j)
    demos[0][:4, 1] += 0.6 * np.linspace(1.0, 0.0, 4)
    canal = canal_core.fit(demos, n_samples=120)
    k = 60
    ball = {"kind": "sphere", "center": (canal.directrix[k] + 0.1 * canal.normals[k]).tolist(), "radius": 0.55}
    scene = scene_from_list([ball], 3)
    tables = scene_tables(canal.tracker_geometry(), scene, canal.section_steps)
    assert 0.0 < tables.free[k].max() < 0.5 * canal.largest_step  # a passage, narrower than that
    offline = canal.reproduce_detailed(canal.directrix[0], obstacles=scene)
    assert offline.blocked is None
    poses, targets, statuses, done = drive(canal, [ball], canal.directrix[0], steps=600)
    assert done.all(), statuses[-1]
    assert (statuses == DETOUR).any() and not (statuses == BLOCKED).any()
    assert free_distances(poses.reshape(-1, 3), scene).min() >= 0.0
    assert free_distances(targets.reshape(-1, 3), scene).min() >= 0.0


def test_a_long_last_step_of_one_demonstration_does_not_shut_the_goal_off() -> None:
    # One demonstration ends far aside: its last step is twelve times the usual one. A ball
    # leaves the goal a few usual steps of room; the goal stays a place a detour may aim.
    demos = tube_demos(radius=0.5, n_demos=6, n_points=80)
    demos[0][-4:, 1] += 0.6 * np.linspace(0.0, 1.0, 4)
    canal = canal_core.fit(demos, n_samples=120)
    goal = canal.directrix[-1]
    ball = {"kind": "sphere", "center": (goal + 0.35 * canal.normals[-1]).tolist(), "radius": 0.3}
    tables = scene_tables(canal.tracker_geometry(), scene_from_list([ball], 3), canal.section_steps)
    assert canal.section_steps[-1] > 10 * np.median(canal.section_steps)
    centre = np.linalg.norm(tables.candidates[-1] - goal, axis=1).argmin()
    assert tables.free[-1, centre] < 0.5 * canal.section_steps[-1]
    assert tables.usable[-1, centre] and tables.lane_clear[-1, centre]


def test_a_wall_holds_the_robots_before_it(tube: canal_core.Canal) -> None:
    k = 60
    axes = np.stack([tube.tangents[k], tube.normals[k], tube.binormals[k]], axis=1)
    wall = {"kind": "box", "center": tube.directrix[k].tolist(), "half_extents": [0.02, 2.0, 2.0],
            "rotation": rotation_parameters(axes)}
    poses, _targets, statuses, done = drive(tube, [wall], tube.directrix[0], steps=300)
    assert not done.any()
    assert (statuses[-20:] == BLOCKED).all()
    assert ((poses.reshape(-1, 3) - tube.directrix[k]) @ tube.tangents[k]).max() < -0.02


def test_a_robot_inside_two_overlapping_obstacles_is_backed_out_of_both() -> None:
    # Two discs that overlap (one object made of two): out along the deepest one's normal is
    # into the other. Each answer must leave the robot no deeper, and it gets out.
    x = np.linspace(0.0, 1.0, 60)
    demos = [np.column_stack([x, 0.05 * np.cos(np.pi * j / 2) + 0.01 * np.sin(7.0 * x + j)]) for j in range(4)]
    canal = canal_core.fit(demos, [np.linspace(0.0, 2.0, 60)] * 4)
    discs = [{"kind": "disc", "center": [0.5, 0.0], "radius": 0.03},
             {"kind": "disc", "center": [0.5, 0.04], "radius": 0.03}]
    scene = scene_from_list(discs, 2)
    bank = TrackerBank(canal.tracker_geometry(), 2, compiled=False)
    bank.scene = scene_tables(bank.geometry, scene, canal.section_steps)
    slot = bank.add(int(canal.reproduce_detailed(np.array([0.5, 0.02])).section_index))
    pos = np.array([[0.5, 0.02]])
    free = [float(free_distances(pos, scene)[0])]
    for _ in range(20):
        rows = bank.step_packed([slot], pos)
        status = int(bank.avoid_packed(rows, pos)[0])
        if status != IN_OBSTACLE:
            break
        pos = rows[:, :2].copy()
        free.append(float(free_distances(pos, scene)[0]))
    assert free[0] < 0.0 and free[-1] >= 0.0, free
    assert (np.diff(free) >= 0.0).all(), free


def test_a_thin_wall_between_two_planes_holds_a_robot_blocked_and_still() -> None:
    # A plate 1 mm thick across a flat canal, between two section planes: no candidate of any
    # section lies in it, but every step across it does. A robot that goes exactly to each
    # target is held before it, told so, and not slid along the wall.
    x = np.linspace(0.0, 1.0, 60)
    demos = [np.column_stack([x, o + 0.002 * np.sin(7.0 * x + i)])
             for i, o in enumerate((0.05, -0.05, 0.025, -0.025))]
    canal = canal_core.fit(demos, [np.linspace(0.0, 2.0, 60)] * 4)
    plate = {"kind": "box", "center": [0.5, 0.0], "half_extents": [0.0005, 1.0]}
    scene = scene_from_list([plate], 2)
    assert canal.reproduce_detailed(np.zeros(2), obstacles=scene).blocked is not None
    bank = TrackerBank(canal.tracker_geometry(), 2, compiled=False)
    bank.scene = scene_tables(bank.geometry, scene, canal.section_steps)
    slot = bank.add(0)
    pos = np.zeros((1, 2))
    poses, statuses, velocities = [], [], []
    for _ in range(300):
        rows = bank.step_packed([slot], pos)
        statuses.append(int(bank.avoid_packed(rows, pos)[0]))
        poses.append(pos[0].copy())
        velocities.append(rows[0, 7:9].copy())  # packed: target (2), 5 scalars, velocity (2)
        pos = rows[:, :2].copy()
    poses_ = np.array(poses)
    assert poses_[:, 0].max() < 0.4995
    assert all(st == BLOCKED for st in statuses[-100:])
    assert np.abs(np.diff(poses_[-100:], axis=0)).max() == 0.0
    # A timed canal gives a feed-forward velocity; a held robot is given none towards the wall.
    assert np.linalg.norm(velocities[0]) > 0.0
    assert all(np.array_equal(v, np.zeros(2)) for v, st in zip(velocities, statuses, strict=True) if st != OK)


def test_a_robot_inside_an_obstacle_is_told_and_backed_away(tube: canal_core.Canal) -> None:
    x = tube.directrix[20] + np.array([0.0, 0.05, 0.0])
    ball = {"kind": "sphere", "center": tube.directrix[20].tolist(), "radius": 0.15}
    bank = TrackerBank(tube.tracker_geometry(), 2, compiled=False)
    bank.scene = scene_tables(bank.geometry, scene_from_list([ball], 3), tube.section_steps)
    slot = bank.add(20)
    rows = bank.step_packed([slot], x[None])
    status = bank.avoid_packed(rows, x[None])
    assert status is not None and status[0] == IN_OBSTACLE
    target = rows[0, :3]
    assert np.linalg.norm(target - tube.directrix[20]) > np.linalg.norm(x - tube.directrix[20])
    assert np.linalg.norm(target - x) <= tube.largest_step + 1e-12
    # Away from every obstacle the tracker's answer is left as it is.
    far = tube.directrix[100][None]
    slot2 = bank.add(99)
    rows = bank.step_packed([slot2], far)
    plain = rows.copy()
    assert bank.avoid_packed(rows, far)[0] == OK
    np.testing.assert_array_equal(rows, plain)


def test_a_robot_held_beside_an_obstacle_over_the_goal_is_done_not_blocked() -> None:
    # A sphere over the canal's end: a reproduction ends beside it, unblocked. A live robot
    # that follows its targets arrives there too and is held; it was told `blocked` with
    # `done` for good, as though the scene closed the canal ahead of a robot that finished.
    canal = ring_canal()
    scene = scene_from_list([{"kind": "sphere", "center": [1.0, 0.0, 0.0], "radius": 0.03}], 3)
    assert canal.reproduce_detailed([0.0, 0.01, 0.0], obstacles=scene).blocked is None
    bank = TrackerBank(canal.tracker_geometry(), 2, compiled=False)
    bank.scene = scene_tables(bank.geometry, scene, canal.section_steps)
    slot = bank.add(0)
    pos = np.array([[0.0, 0.01, 0.0]])
    seen = []
    for _ in range(200):
        rows = bank.step_packed([slot], pos)
        status = int(bank.avoid_packed(rows, pos)[0])
        done = bool(rows[0, 3 + 4] > 0.5)  # packed: target (3), progress, eta, section, inside, done
        seen.append((status, done))
        pos = pos + 0.5 * (rows[:, :3] - pos)
    assert seen[-1][1]  # the robot finished
    assert not any(status == BLOCKED for status, _ in seen)


@pytest.mark.parametrize("compiled", [False, True])
def test_a_glitch_pose_inside_an_obstacle_does_not_move_the_target(
        tube: canal_core.Canal, compiled: bool) -> None:
    # The tracker held a glitch pose (the plan kept), but the obstacle pass judged the scene
    # from the glitch itself and backed the "robot" out of an obstacle near the canal's end:
    # one bad sample moved the target most of the canal's length.
    ball = {"kind": "sphere", "center": tube.directrix[-3].tolist(), "radius": 0.15}
    bank = TrackerBank(tube.tracker_geometry(), 2, compiled=compiled)
    bank.scene = scene_tables(bank.geometry, scene_from_list([ball], 3), tube.section_steps)
    slot = bank.add(0)
    x = tube.directrix[0].copy()
    for _ in range(40):
        rows = bank.step_packed([slot], x[None])
        assert bank.avoid_packed(rows, x[None], [slot])[0] == OK
        x = x + 0.6 * (rows[0, :3] - x)
    before = rows[0, :3].copy()
    glitch = tube.directrix[-3][None]
    rows = bank.step_packed([slot], glitch)
    status = int(bank.avoid_packed(rows, glitch, [slot])[0])
    assert status == OK and rows[0, 6] == 0.0, (status, rows[0])  # held: outside, no obstacle
    assert np.linalg.norm(rows[0, :3] - before) < 3 * tube.largest_step, (rows[0, :3], before)
