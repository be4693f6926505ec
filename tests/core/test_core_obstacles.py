"""Obstacles: distances, segment checks, and reproductions through the free part of the canal."""

from __future__ import annotations

import numpy as np
import pytest
from core_data import ring_canal, tube_demos

import canal_core
from canal_core import InvalidInputError
from canal_core.obstacles import (
    FREE_BLOCK,
    free_distances,
    obstacle_free_distances,
    scene_from_list,
    segment_free_distances,
)


def _dense_free(p: np.ndarray, q: np.ndarray, scene: canal_core.obstacles.Scene, n: int = 400) -> np.ndarray:
    """Smallest free distance along each segment, sampled densely (an independent check)."""
    t = np.linspace(0.0, 1.0, n)
    pts = p[:, None, :] + t[None, :, None] * (q - p)[:, None, :]
    return free_distances(pts.reshape(-1, p.shape[1]), scene).reshape(p.shape[0], n).min(axis=1)


def _box_distance_brute(x: np.ndarray, centre: np.ndarray, rot: np.ndarray, half: np.ndarray) -> np.ndarray:
    """Distance outside a box from a dense sampling of its surface."""
    g = np.linspace(-1.0, 1.0, 41)
    faces = []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            a, b = np.meshgrid(g, g)
            f = np.zeros((a.size, 3))
            others = [k for k in range(3) if k != axis]
            f[:, axis] = sign
            f[:, others[0]] = a.ravel()
            f[:, others[1]] = b.ravel()
            faces.append(f)
    surface = centre + (np.vstack(faces) * half) @ rot.T
    return np.asarray(np.sqrt(((x[:, None, :] - surface[None]) ** 2).sum(axis=2)).min(axis=1))


def test_distances_of_each_kind_match_their_geometry() -> None:
    q = [0.0, 0.0, np.sin(np.pi / 8), np.cos(np.pi / 8)]  # 45 degrees about z
    scene = scene_from_list(
        [
            {"kind": "sphere", "center": [0, 0, 0], "radius": 1.0, "clearance": 0.1},
            {"kind": "capsule", "a": [5, 0, 0], "b": [5, 4, 0], "radius": 0.5},
            {"kind": "box", "center": [-5, 0, 0], "half_extents": [1.0, 0.5, 0.25], "rotation": q},
        ],
        3,
    )
    from canal_core.obstacles import obstacle_free_distances

    pts = np.array([[2.0, 0, 0], [0.5, 0, 0], [5, 2, 1], [5, 6, 0], [-5, 0, 3.0]])
    d = obstacle_free_distances(pts, scene)
    np.testing.assert_allclose(d[0, 0], 0.9)  # 2 - 1 - clearance
    assert d[1, 0] < 0.0  # inside the sphere
    np.testing.assert_allclose(d[2, 1], 0.5)  # 1 above the capsule's axis
    np.testing.assert_allclose(d[3, 1], 1.5)  # 2 past its end
    np.testing.assert_allclose(d[4, 2], 2.75)  # above the rotated box's top face
    rng = np.random.default_rng(3)
    far = np.array([-5.0, 0.0, 0.0]) + rng.normal(scale=2.0, size=(50, 3))
    box = scene.obstacles[2]
    outside = d_box = obstacle_free_distances(far, scene)[:, 2]
    brute = _box_distance_brute(far, box.center, box.rotation, box.half_extents)
    outside = d_box > 0.0
    np.testing.assert_allclose(d_box[outside], brute[outside], atol=0.02)


def test_segment_check_sees_what_passes_between_the_ends() -> None:
    scene = scene_from_list(
        [
            {"kind": "sphere", "center": [0, 0, 0], "radius": 0.2},
            {"kind": "capsule", "a": [3, -1, 0], "b": [3, 1, 0], "radius": 0.1},
            {"kind": "box", "center": [6, 0, 0], "half_extents": [0.1, 0.1, 0.1], "rotation": [0, 0, 0.3826834, 0.9238795]},
        ],
        3,
    )
    # Segments whose ends are far from every obstacle but which cross one.
    p = np.array([[-1.0, 0.05, 0], [3, 0.5, -1.0], [6, 0.05, -1.0], [-1.0, 1.0, 0.0]])
    q = np.array([[1.0, 0.05, 0], [3, 0.5, 1.0], [6, 0.05, 1.0], [1.0, 1.0, 0.0]])
    ends = np.minimum(free_distances(p, scene), free_distances(q, scene))
    assert (ends[:3] > 0.5).all()
    exact = segment_free_distances(p, q, scene)
    dense = _dense_free(p, q, scene, 4000)
    assert (exact[:3] < 0.0).all()
    assert exact[3] > 0.0
    np.testing.assert_allclose(exact[[0, 1, 3]], dense[[0, 1, 3]], atol=1e-3)
    assert exact[2] < 0.0  # boxes too: it enters the box
    np.testing.assert_allclose(exact, dense, atol=1e-3)
    # A segment that passes beside the box is measured no further from it than it is.
    beside = segment_free_distances(np.array([[6.3, 0.0, -1.0]]), np.array([[6.3, 0.0, 1.0]]), scene)
    dense_beside = _dense_free(np.array([[6.3, 0.0, -1.0]]), np.array([[6.3, 0.0, 1.0]]), scene, 4000)
    assert 0.0 < beside[0] <= dense_beside[0] + 1e-9


def test_a_step_through_a_thin_wall_is_not_clear(tube: canal_core.Canal) -> None:
    # A step 2.5 wall-thicknesses long, whose ends lie 2 mm and 16 mm from a 2 cm slab across
    # the canal, passes through it. The march from its ends stopped at the slab's faces and
    # said "touching" (0), which the path check took as clear: the reproduction went through
    # a door across the canal, all its points outside the wall, and was not blocked.
    slab = {"kind": "box", "center": [0.0, 0.0, 0.0], "half_extents": [0.01, 0.5, 0.5]}
    scene = scene_from_list([slab], 3)
    p, q = np.array([[-0.012, 0.0, 0.0]]), np.array([[0.026, 0.03, 0.0]])
    assert (free_distances(np.vstack([p, q]), scene) > 0.0).all()
    free = segment_free_distances(p, q, scene)
    np.testing.assert_allclose(free, _dense_free(p, q, scene, 4000), atol=1e-5)
    assert free[0] == pytest.approx(-0.01, abs=1e-6)
    # ... and a door across the canal, as the reproduction meets it
    x = float(tube.directrix[len(tube.directrix) // 2, 0])
    wall = {"kind": "box", "center": [x, 0.0, 0.0], "half_extents": [0.01, 2.0, 2.0]}
    rep = tube.reproduce_detailed(np.array([0.0, 0.1, 0.0]), obstacles=[wall])
    assert rep.blocked is not None and rep.blocked.reason == "closed"
    assert (rep.positions[:, 0] < x - 0.01).all()


def test_malformed_obstacles_are_refused_naming_the_field() -> None:
    cases = [
        ([{"kind": "sphere", "center": [0, 0, 0], "radius": -1.0}], "obstacles[0].radius"),
        ([{"kind": "sphere", "center": [0, 0, float("nan")], "radius": 1.0}], "obstacles[0].center"),
        ([{"kind": "sphere", "center": [0, 0], "radius": 1.0}], "obstacles[0].center"),
        ([{"kind": "disc", "center": [0, 0], "radius": 1.0}], "obstacles[0].kind"),
        ([{"kind": "box", "center": [0, 0, 0], "half_extents": [1, 0, 1]}], "obstacles[0].half_extents"),
        ([{"kind": "box", "center": [0, 0, 0], "half_extents": [1, 1, 1], "rotation": [1, 1, 0, 0]}],
         "obstacles[0].rotation"),
        ([{"kind": "capsule", "a": [0, 0, 0], "radius": 1.0}], "obstacles[0].b"),
        ([{"kind": "sphere", "center": [0, 0, 0], "radius": 1.0, "clearance": -0.1}], "obstacles[0].clearance"),
        ([{"kind": "sphere", "center": [0, 0, 0], "radius": 1.0, "colour": "red"}], "obstacles[0].colour"),
        ({"kind": "sphere"}, "obstacles"),
    ]
    for items, field in cases:
        with pytest.raises(InvalidInputError) as info:
            scene_from_list(items, 3)
        assert info.value.field == field, (items, info.value.message)
        assert "expected" in info.value.message and "got" in info.value.message


def test_scene_round_trips_through_its_json_form() -> None:
    items = [
        {"kind": "box", "center": [1, 2, 3], "half_extents": [0.1, 0.2, 0.3],
         "rotation": [0.0, 0.0, 0.3826834323650898, 0.9238795325112867], "clearance": 0.01, "name": "fixture"},
        {"kind": "capsule", "a": [0, 0, 0], "b": [1, 0, 0], "radius": 0.1, "clearance": 0.0},
    ]
    scene = scene_from_list(items, 3)
    again = scene_from_list(scene.to_list(), 3)
    pts = np.random.default_rng(0).normal(size=(20, 3))
    np.testing.assert_allclose(free_distances(pts, again), free_distances(pts, scene), atol=1e-12)
    assert again.obstacles[0].name == "fixture"


@pytest.fixture(scope="module")
def tube() -> canal_core.Canal:
    """A straight tube whose demos wander sideways, as hands do (their steps leave room to swerve)."""
    demos = tube_demos(radius=0.5, n_demos=6, n_points=80)
    for j, d in enumerate(demos):
        d[:, 1] += 0.08 * np.sin(2.0 * d[:, 0] + j)
        d[:, 2] += 0.08 * np.cos(2.5 * d[:, 0] + 2 * j)
    return canal_core.fit(demos, n_samples=120)


def test_parallel_demos_leave_no_room_to_swerve_within_their_step() -> None:
    """Demos that never move sideways: a detour would step further than they ever did."""
    canal = canal_core.fit(tube_demos(radius=0.5, n_demos=6, n_points=80), n_samples=120)
    ball = {"kind": "sphere", "center": [2.0, 0.2, 0.0], "radius": 0.15}
    rep = canal.reproduce_detailed(np.array([0.0, 0.2, 0.0]), obstacles=[ball])
    assert rep.blocked is not None and rep.blocked.reason == "unreachable"
    assert rep.blocked.obstacles == (0,)
    assert rep.positions[-1, 0] < 2.0 - 0.15


@pytest.mark.parametrize("wall", [
    {"kind": "capsule", "a": [0.5, -1.0], "b": [0.5, 1.0], "radius": 0.001},
    {"kind": "box", "center": [0.5, 0.0], "half_extents": [0.0005, 1.0]},
])
def test_an_unreachable_section_names_the_obstacle_in_the_way(wall: dict[str, object]) -> None:
    # A wall a millimetre thin across a 2-D canal, between two section planes: no candidate
    # of the section beyond it lies inside it, so the answer said unreachable naming no
    # obstacle. It names the wall, and not a disc off to the side.
    x = np.linspace(0.0, 1.0, 60)
    demos = [np.column_stack([x, o + 0.002 * np.sin(7 * x + i)])
             for i, o in enumerate((0.05, -0.05, 0.025, -0.025))]
    canal = canal_core.fit(demos, [np.linspace(0.0, 2.0, 60)] * 4)
    aside = {"kind": "disc", "center": [0.3, 0.5], "radius": 0.01}
    rep = canal.reproduce_detailed(np.array([0.0, 0.0]), obstacles=[aside, wall])
    assert rep.blocked is not None and rep.blocked.reason == "unreachable"
    assert rep.blocked.obstacles == (1,)
    assert rep.positions[-1, 0] < 0.5


def _check_path(canal: canal_core.Canal, rep: canal_core.Reproduction, scene: canal_core.obstacles.Scene) -> None:
    p = rep.positions
    # Every segment after the start keeps the clearance, measured densely (not by our own test).
    assert _dense_free(p[:-1], p[1:], scene).min() >= -1e-9
    assert canal.contains(p[1:]).all()
    steps = np.linalg.norm(np.diff(p[1:], axis=0), axis=1)
    assert steps.max() <= canal.largest_step + 1e-12


def test_a_sphere_on_the_path_is_passed_inside_the_canal_with_its_clearance(tube: canal_core.Canal) -> None:
    start = np.array([0.0, 0.2, 0.0])
    plain = tube.reproduce_detailed(start)
    obstacle = {"kind": "sphere", "center": [2.0, 0.2, 0.0], "radius": 0.15, "clearance": 0.05}
    scene = scene_from_list([obstacle], 3)
    # Without the scene the path goes straight through it.
    assert segment_free_distances(plain.positions[:-1], plain.positions[1:], scene).min() < 0.0
    rep = tube.reproduce_detailed(start, obstacles=[obstacle])
    assert rep.blocked is None
    assert rep.detoured is not None and rep.detoured.any()
    _check_path(tube, rep, scene)
    # Away from the obstacle it is the ratio rule's path, and it ends where that one does.
    far = np.abs(plain.positions[1:, 0] - 2.0) > 1.5
    np.testing.assert_allclose(rep.positions[1:][far], plain.positions[1:][far])
    np.testing.assert_allclose(rep.positions[-1], plain.positions[-1])
    assert rep.start_clearance is not None and rep.start_clearance > 0.0
    # Its ratios are those of the path it took: the ratio rule's away from the obstacle, the
    # detour's own beside it (where it swerved, it is not where the rule put it).
    assert rep.ratios is not None and plain.ratios is not None
    np.testing.assert_allclose(rep.ratios[1:][far], plain.ratios[1:][far], atol=1e-9)
    swerved = np.flatnonzero(rep.detoured)
    assert np.abs(rep.ratios[1:][swerved] - plain.ratios[1:][swerved]).max() > 0.05
    assert np.all(rep.ratios[1:] <= 1.0 + 1e-6)  # inside the canal all the way


def test_boxes_and_capsules_are_passed_too(tube: canal_core.Canal) -> None:
    start = np.array([0.0, 0.0, -0.2])
    items = [
        {"kind": "box", "center": [1.2, 0.0, -0.2], "half_extents": [0.1, 0.2, 0.1],
         "rotation": [0.0, 0.3826834323650898, 0.0, 0.9238795325112867], "clearance": 0.02},
        {"kind": "capsule", "a": [2.8, -0.3, -0.1], "b": [2.8, 0.3, -0.3], "radius": 0.08, "clearance": 0.02},
    ]
    scene = scene_from_list(items, 3)
    rep = tube.reproduce_detailed(start, obstacles=items)
    assert rep.blocked is None
    _check_path(tube, rep, scene)


def test_a_section_closed_by_an_obstacle_blocks_the_reproduction_before_it(tube: canal_core.Canal) -> None:
    wall = {"kind": "box", "center": [2.0, 0.0, 0.0], "half_extents": [0.05, 1.0, 1.0], "name": "wall"}
    scene = scene_from_list([wall], 3)
    rep = tube.reproduce_detailed(np.array([0.0, 0.1, 0.1]), obstacles=[wall])
    assert rep.blocked is not None
    assert rep.blocked.reason == "closed" and rep.blocked.obstacles == (0,)
    closed = tube.directrix[rep.blocked.section, 0]
    assert 1.9 <= closed <= 2.1
    # It stops before the wall and never enters it.
    assert rep.positions[:, 0].max() < 1.95
    assert _dense_free(rep.positions[:-1], rep.positions[1:], scene).min() >= 0.0
    assert rep.positions.shape[0] == rep.blocked.section - rep.section_index
    assert rep.ratios is not None and rep.ratios.shape == (rep.positions.shape[0],)
    assert rep.times is None or rep.times.shape[0] == rep.positions.shape[0]


def test_a_start_inside_an_obstacle_leaves_it_and_says_so(tube: canal_core.Canal) -> None:
    start = np.array([0.2, 0.0, 0.0])
    # Within the clearance, a step from the surface: the path leaves and goes on.
    ball = {"kind": "sphere", "center": [0.2, 0.0, 0.1], "radius": 0.09, "clearance": 0.02}
    scene = scene_from_list([ball], 3)
    rep = tube.reproduce_detailed(start, obstacles=[ball])
    assert rep.start_clearance is not None and rep.start_clearance < 0.0
    assert rep.blocked is None
    assert _dense_free(rep.positions[1:-1], rep.positions[2:], scene).min() >= 0.0
    # Deep inside: it does not jump out, it backs out in the demonstrations' steps, each
    # further from the surface, and says where it started.
    deep = {"kind": "sphere", "center": [0.2, 0.0, 0.0], "radius": 0.2}
    out = tube.reproduce_detailed(start, obstacles=[deep])
    assert out.blocked is None and out.start_clearance is not None and out.start_clearance < -0.19
    free = free_distances(out.positions, scene_from_list([deep], 3))
    left = int(np.argmax(free >= 0.0))
    assert 1 <= left <= out.approach and np.all(np.diff(free[: left + 1]) > 0.0)
    assert np.linalg.norm(np.diff(out.positions[: left + 1], axis=0), axis=1).max() <= tube.largest_step * (1 + 1e-9)
    # Too deep to back out in 64 such steps: it says where it is, and does not move.
    stuck = tube.reproduce_detailed(start, obstacles=[{"kind": "sphere", "center": [0.2, 0.0, 0.0], "radius": 3.0}])
    assert stuck.blocked is not None and stuck.blocked.reason in ("start", "closed")
    assert stuck.positions.shape == (1, 3)


def test_2d_discs_and_boxes(rng: np.random.Generator) -> None:
    x = np.linspace(0.0, 4.0, 60)
    demos = [np.column_stack([x, off + 0.02 * np.sin(3 * x)]) for off in (-0.5, -0.2, 0.1, 0.5)]
    canal = canal_core.fit(demos, n_samples=100)
    start = np.array([0.0, 0.0])
    disc = {"kind": "disc", "center": [2.0, 0.0], "radius": 0.15, "clearance": 0.02}
    rep = canal.reproduce_detailed(start, obstacles=[disc])
    assert rep.blocked is None
    _check_path(canal, rep, scene_from_list([disc], 2))
    wall = {"kind": "box", "center": [3.0, 0.0], "half_extents": [0.05, 2.0], "rotation": 0.3}
    blocked = canal.reproduce_detailed(start, obstacles=[disc, wall])
    assert blocked.blocked is not None and blocked.blocked.obstacles == (1,)
    assert blocked.positions[:, 0].max() < 3.0 + 2.0 * np.sin(0.3)
    both = scene_from_list([disc, wall], 2)
    assert _dense_free(blocked.positions[:-1], blocked.positions[1:], both).min() >= 0.0
    with pytest.raises(InvalidInputError) as info:
        canal.reproduce_detailed(start, obstacles=[{"kind": "sphere", "center": [2, 0, 0], "radius": 1}])
    assert info.value.field == "obstacles[0].kind"


def test_a_start_outside_a_narrowing_canal_still_goes_around_a_sphere() -> None:
    """Generated raw logs of the paper's Task I (the canal narrows to a centimetre), a start
    outside it (the path rides the boundary) and a sphere where it narrows: the detour is found
    (it was reported unreachable with too few shift directions)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from raw_logs import raw_demo_set

    from canal_core.preprocess import cleaned_demonstration

    logs = raw_demo_set("task1", 0)
    demos = [cleaned_demonstration(g.positions[g.genuine], g.timestamps[g.genuine]) for g in logs]
    train = demos[:2] + demos[3:]
    canal = canal_core.fit([p for p, _ in train], [t for _, t in train], n_samples=200)
    ball = {"kind": "sphere", "center": [0.4476926748531478, -0.0061539347237186525, 0.19548483740446815],
            "radius": 0.026299519212005913}
    rep = canal.reproduce_detailed(demos[2][0][0], obstacles=[ball])
    assert rep.projected and rep.blocked is None
    p = rep.positions
    assert segment_free_distances(p[:-1], p[1:], scene_from_list([ball], 3)).min() >= 0.0


def test_a_long_step_that_passes_beside_an_obstacle_is_kept(tube: canal_core.Canal) -> None:
    """A start placed on the last section from far away (a pressing motion starts where it
    ends): one long step, beside a sphere but clear of it. The Lipschitz test alone refused it
    and the reproduction was blocked at the last section with no obstacle there."""
    from canal_core.obstacles import avoided_path

    end = tube.directrix[-1]
    start = end - np.array([1.0, 0.0, 0.0])
    scene = scene_from_list([{"kind": "sphere", "center": (end - [0.5, -0.3, 0.0]).tolist(), "radius": 0.1}], 3)
    result = avoided_path(start, end[None, :], tube.n_sections - 1, tube.directrix, tube.basis,
                          tube.sections, scene, tube.largest_step)
    assert result.blocked is None
    np.testing.assert_array_equal(result.positions, np.vstack([start, end]))


def test_free_distances_in_blocks_match_the_table_of_every_obstacle() -> None:
    # Spheres, capsules and boxes together, over more points than one block: the smallest
    # of each point's row of the table, exactly.
    rng = np.random.default_rng(1)
    items: list[dict[str, object]] = [
        {"kind": "sphere", "center": rng.normal(size=3).tolist(), "radius": 0.1, "clearance": 0.01}
        for _ in range(5)]
    items += [{"kind": "capsule", "a": rng.normal(size=3).tolist(), "b": rng.normal(size=3).tolist(),
               "radius": 0.1} for _ in range(3)]
    items += [{"kind": "box", "center": rng.normal(size=3).tolist(), "half_extents": [0.1, 0.2, 0.3]}
              for _ in range(2)]
    scene = scene_from_list(items, 3)
    points = rng.normal(size=(FREE_BLOCK + 17, 3))
    np.testing.assert_array_equal(free_distances(points, scene), obstacle_free_distances(points, scene).min(axis=1))
    spheres = scene_from_list(items[:5], 3)
    np.testing.assert_array_equal(free_distances(points, spheres),
                                  obstacle_free_distances(points, spheres).min(axis=1))


def test_a_start_within_a_clearance_deeper_than_a_step_can_swerve_backs_out_first() -> None:
    # A start 5-7 mm from a sphere whose clearance is 10 mm, in a canal whose demonstrations
    # barely move sideways: the ratio rule's first step cannot leave the clearance, and the
    # reproduction was blocked at the start, with no move, where the live pass backs the
    # robot out. It now backs out first, in steps no longer than the demonstrations' largest,
    # each further from the sphere, then follows the canal.
    canal = ring_canal()
    start = np.array([0.0, 0.01, 0.0])
    for depth in (0.003, 0.005):
        ball = {"kind": "sphere", "center": [0.0, 0.04 - depth, 0.0], "radius": 0.02, "clearance": 0.01}
        scene = scene_from_list([ball], 3)
        result = canal.reproduce_detailed(start, obstacles=scene)
        assert result.start_clearance is not None and result.start_clearance < 0.0
        assert result.blocked is None, (depth, result.blocked)
        free = free_distances(result.positions, scene)
        out = int(np.argmax(free >= 0.0))
        assert out >= 1 and (free[out:] >= -1e-12).all()
        assert np.all(np.diff(free[: out + 1]) > 0.0)  # backing out: ever further
        steps = np.linalg.norm(np.diff(result.positions, axis=0), axis=1)
        assert steps[:out].max() <= canal.largest_step * (1.0 + 1e-9)
        assert result.approach >= out - 1
        assert np.all(np.diff(result.times) > 0.0)
