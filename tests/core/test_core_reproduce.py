"""Reproduction by the ratio rule (Section 4.2), Task I/II, starts anywhere, outside starts."""

from __future__ import annotations

import json
import tracemalloc

import numpy as np
import pytest
from core_data import helix_demos, ring_canal, sleeve_demos

import canal_core
from canal_core import OutsideCanalError, datasets
from canal_core.cross_sections import boundary_distance
from canal_core.entry import approach_shares

KINDS = ("circle", "mec", "ellipse", "spline")


def eta_along(canal: canal_core.Canal, path: np.ndarray) -> np.ndarray:
    loc = canal.locate(path)
    return loc.eta


@pytest.mark.parametrize("kind", KINDS)
def test_task_one_reproduction_passes_the_narrow_middle(kind: str, rng: np.random.Generator) -> None:
    canal = canal_core.fit(datasets.task_one(), cross_section=kind)
    for _ in range(5):
        # A random start inside the first cross-section.
        angle = rng.uniform(0, 2 * np.pi)
        radius = rng.uniform(0, 0.9) * 0.2
        start = np.array([0.0, radius * np.cos(angle), radius * np.sin(angle)])
        result = canal.reproduce_detailed(start)
        assert result.inside and not result.projected
        path = result.positions
        assert canal.contains(path).all()
        # In the middle (x = 0.5) the canal is 1 cm wide: the reproduction passes within it.
        middle = path[np.argmin(np.abs(path[:, 0] - 0.5))]
        assert np.hypot(middle[1], middle[2]) <= 0.0101
        np.testing.assert_allclose(path[-1, 0], 1.0, atol=1e-9)  # ends at the canal's end


@pytest.mark.parametrize("kind", KINDS)
def test_eta_is_preserved_along_the_reproduction(kind: str) -> None:
    canal = canal_core.fit(sleeve_demos(), cross_section=kind, n_samples=120)
    start = canal.directrix[10] + 0.6 * 0.05 * canal.normals[10] + 0.2 * 0.05 * canal.binormals[10]
    # The paper's schedule (no end decay): each reproduced point sits exactly in its
    # cross-section at ratio eta.
    result = canal.reproduce_detailed(start, end_decay=0.0, persistence="constant")
    idx = np.arange(result.section_index + 1, canal.n_sections)
    rel = result.positions[1:] - canal.directrix[idx]
    q = np.einsum("nkd,nd->nk", canal.basis[idx], rel)
    norm = np.linalg.norm(q, axis=1)
    reach = boundary_distance(canal.sections, idx, q / norm[:, None])
    np.testing.assert_allclose(norm / reach, result.eta, rtol=1e-9)
    axial = np.einsum("nd,nd->n", rel, canal.tangents[idx])
    assert np.abs(axial).max() < 1e-12


@pytest.mark.parametrize("kind", KINDS)
def test_ratios_say_how_far_out_each_position_is(kind: str) -> None:
    canal = canal_core.fit(sleeve_demos(), cross_section=kind, n_samples=120)
    start = canal.directrix[10] + 0.6 * 0.05 * canal.normals[10] + 0.2 * 0.05 * canal.binormals[10]
    constant = canal.reproduce_detailed(start, end_decay=0.0, persistence="constant")
    assert constant.ratios is not None and constant.ratios.shape == (len(constant.positions),)
    np.testing.assert_allclose(constant.ratios, constant.eta, rtol=1e-9)  # the paper's rule
    # The defaults: the start's ratio, faded by what the demos kept and onto the end.
    learned = canal.reproduce_detailed(start)
    assert learned.ratios is not None
    assert learned.ratios[0] == pytest.approx(learned.eta)
    assert learned.ratios[-1] == pytest.approx(0.0, abs=1e-9)
    assert np.all(learned.ratios <= learned.eta + 1e-9)  # inside stays inside
    # Each value is the position's ratio in its section, as locating it finds it.
    middle = slice(1, len(learned.positions) // 2)
    np.testing.assert_allclose(learned.ratios[middle], eta_along(canal, learned.positions[middle]),
                               rtol=1e-6, atol=1e-9)


def test_ratios_of_a_start_outside_show_its_entry() -> None:
    canal = canal_core.fit(datasets.task_one())
    result = canal.reproduce_detailed(np.array([0.0, 0.5, 0.0]))
    assert result.ratios is not None
    assert result.ratios[0] == pytest.approx(2.5, rel=1e-6)  # the start's own, not the clamp's 1
    assert np.all(result.ratios[1:result.entry_index] > 1.0)
    assert np.all(result.ratios[result.entry_index:] <= 1.0 + 1e-6)
    # behind the first plane: the approach's points are read in the first plane
    behind = canal.reproduce_detailed(canal.directrix[0] - 0.3 * canal.tangents[0]
                                      + 0.01 * canal.normals[0])
    assert behind.approach > 0 and behind.ratios is not None
    assert behind.ratios.shape == (len(behind.positions),) and np.isfinite(behind.ratios).all()


def test_start_is_matched_to_its_nearest_section_not_the_first() -> None:
    canal = canal_core.fit(helix_demos(), n_samples=150)
    start = canal.directrix[90] + 0.02 * canal.normals[90]
    result = canal.reproduce_detailed(start)
    assert result.section_index in (89, 90)
    assert result.positions.shape[0] == 1 + canal.n_sections - 1 - result.section_index
    # The offset fades into the last sections: the reproduction lands on the canal's end.
    np.testing.assert_allclose(result.positions[-1], canal.directrix[-1], atol=1e-12)
    paper = canal.reproduce_detailed(start, end_decay=0.0, persistence="constant")
    np.testing.assert_allclose(paper.positions[-1], canal.directrix[-1] + result.eta * canal.radii[-1] * canal.normals[-1], atol=1e-9)


def test_a_start_behind_the_first_plane_on_the_line_of_the_last_section_starts_at_the_beginning() -> None:
    # Up, right, down and back left: the motion ends heading towards where it began, so a
    # start just behind the first plane lies far past the last one, near its normal line,
    # where its ratio across the last section alone is below 1.
    t = np.linspace(0.0, 1.0, 200)
    corners = np.array([[0.0, 0.0], [0.0, 10.0], [20.0, 10.0], [20.0, 0.0], [10.0, 0.0]])
    legs = np.cumsum(np.r_[0.0, np.linalg.norm(np.diff(corners, axis=0), axis=1)])
    path = np.column_stack([np.interp(t * legs[-1], legs, corners[:, d]) for d in range(2)])
    demos = [path + np.array([dx, dy]) for dx, dy in ((-0.4, 0.0), (0.4, 0.0), (0.0, 0.4), (0.0, -0.4))]
    canal = canal_core.fit(demos, n_samples=120, alignment="spline")
    start = np.array([1.2, -0.3])  # beside the first section, behind its plane
    assert (start - canal.directrix[0]) @ canal.tangents[0] < 0.0
    past = (start - canal.directrix[-1]) @ canal.tangents[-1]
    assert past > 5.0 and canal.locate(start[None, :]).eta[0] < 1.0  # across the last: inside
    result = canal.reproduce_detailed(start)
    assert result.section_index == 0
    assert result.positions[:, 1].max() > 9.0  # it goes up first, the whole way round
    # A start past the end, on the line of its last section, still starts at the goal.
    assert canal.reproduce_detailed(canal.directrix[-1] + 0.2 * canal.tangents[-1]).section_index == canal.n_sections - 2


def test_start_on_the_directrix_follows_the_directrix() -> None:
    canal = canal_core.fit(datasets.task_one())
    result = canal.reproduce_detailed(canal.directrix[0])
    assert result.eta == 0.0 and result.inside
    np.testing.assert_allclose(result.positions[1:], canal.directrix[1:], atol=1e-12)
    assert np.isfinite(result.positions).all()


def test_start_outside_is_projected_or_raises() -> None:
    canal = canal_core.fit(datasets.task_one())
    start = np.array([0.0, 0.5, 0.0])  # 2.5 radii out at the first section
    result = canal.reproduce_detailed(start)
    assert not result.inside and result.projected and result.eta == 1.0
    np.testing.assert_array_equal(result.positions[0], start)
    # The path enters the canal by the time the demonstrations have half converged (the canal
    # half as wide as at the start), then stays inside.
    eta = canal.locate(result.positions).eta
    assert np.all(np.diff(eta[:12]) <= 1e-9)
    half = int(np.argmax(canal.radii <= 0.5 * canal.radii[0]))
    assert 0 < result.entry_index <= half + 2
    assert canal.contains(result.positions[result.entry_index:]).all()
    # A fixed entry blend (10 % of the length) enters after that length.
    blended = canal.reproduce_detailed(start, entry=0.1)
    entered = int(np.argmax(canal.arclength[1:] >= canal.arclength[1] + 0.1 * canal.arclength[-1]))
    assert canal.contains(blended.positions[1 + entered:]).all()
    assert eta[1] > 1.5  # the first step does not jump onto the wall
    # entry=0 is the paper's clamp: on the boundary at once.
    assert canal.contains(canal.reproduce_detailed(start, entry=0.0).positions[1:]).all()
    with pytest.raises(OutsideCanalError, match=r"eta=2\.5"):
        canal.reproduce_detailed(start, outside="raise")


def test_two_dimensional_reproduction_keeps_its_side() -> None:
    x = np.linspace(0, 1, 80)
    demos = [np.column_stack([x, 0.3 * np.sin(np.pi * x) + d * (1.2 - x)]) for d in (-0.05, 0.02, 0.1)]
    canal = canal_core.fit(demos, cross_section="ellipse", n_samples=80)
    start = canal.directrix[0] + 0.5 * canal.sections.params["lower"][0] * canal.normals[0]
    path = canal.reproduce_detailed(start, end_decay=0.0, persistence="constant").positions
    side = np.einsum("nd,nd->n", path[1:] - canal.directrix[1:], canal.normals[1:])
    np.testing.assert_allclose(side, 0.5 * canal.sections.params["lower"][1:], rtol=1e-9, atol=1e-15)


@pytest.mark.parametrize("kind", KINDS)
def test_model_round_trips_exactly_through_json(kind: str) -> None:
    canal = canal_core.fit(helix_demos(), cross_section=kind, n_samples=60, frames="frenet")
    text = json.dumps(canal.to_dict())
    again = canal_core.Canal.from_dict(json.loads(text))
    for name in ("directrix", "tangents", "normals", "binormals", "arclength", "section_points", "end_depths", "radii"):
        np.testing.assert_array_equal(getattr(again, name), getattr(canal, name))
    assert again.envelope_margin == canal.envelope_margin
    assert again.options == canal.options
    start = canal.directrix[3] + 0.01 * canal.normals[3]
    np.testing.assert_array_equal(again.reproduce(start), canal.reproduce(start))
    np.testing.assert_array_equal(again.mesh().vertices, canal.mesh().vertices)


def test_from_dict_rejects_foreign_data() -> None:
    data = canal_core.fit(datasets.task_one(n_points=20), n_samples=20).to_dict()
    with pytest.raises(canal_core.ModelFormatError, match="version"):
        canal_core.Canal.from_dict({**data, "version": 99})
    with pytest.raises(canal_core.ModelFormatError, match="shape"):
        canal_core.Canal.from_dict({**data, "directrix": [[0.0, 0.0, 0.0]]})
    with pytest.raises(canal_core.ModelFormatError):
        canal_core.Canal.from_dict({k: v for k, v in data.items() if k != "sections"})


def test_options_are_recorded() -> None:
    canal = canal_core.fit(datasets.task_one(), alignment="dtw", directrix="gmr", n_samples=80)
    assert canal.options.to_dict() == {
        "cross_section": "circle", "frames": "rmf", "alignment": "dtw", "directrix": "gmr", "n_samples": 80,
        "frame_smoothing": 0.02,
    }
    assert canal.directrix.shape == (80, 3)
    for demo in datasets.task_one():
        assert canal.contains(demo, tol=2e-2).mean() > 0.95


def test_models_saved_before_frame_smoothing_load_as_unsmoothed() -> None:
    data = canal_core.fit(datasets.task_one(n_points=40), n_samples=40).to_dict()
    old = {**data, "options": {k: v for k, v in data["options"].items() if k != "frame_smoothing"}}
    assert canal_core.Canal.from_dict(old).options.frame_smoothing == 0.0


@pytest.mark.parametrize("value", [-0.1, 0.5, float("nan"), "x", True])
def test_bad_frame_smoothing_names_the_field(value: object) -> None:
    with pytest.raises(canal_core.InvalidInputError) as err:
        canal_core.fit(datasets.task_one(), frame_smoothing=value)
    assert err.value.field == "frame_smoothing"


def test_smoothed_frames_do_not_twist_on_noisy_demos() -> None:
    # Noisy demos around a straight line: the true canal has no reason to twist, but the
    # finite-difference tangents of the noisy mean swing, and the raw frames pick up twist.
    # A start off the directrix should keep its offset direction (here +y).
    rng = np.random.default_rng(3)
    x = np.linspace(0.0, 1.0, 200)
    demos = [np.column_stack([x, 0.03 * np.cos(a) + 0 * x, 0.03 * np.sin(a) + 0 * x])
             + 0.004 * rng.standard_normal((200, 3)) for a in np.linspace(0, 2 * np.pi, 7)[:-1]]
    start = np.array([0.0, 0.02, 0.0])

    def end_offset(smoothing: float) -> np.ndarray:
        canal = canal_core.fit(demos, frame_smoothing=smoothing)
        path = canal.reproduce_detailed(start, end_decay=0.0, persistence="constant").positions
        return path[-1, 1:] - canal.directrix[-1, 1:]

    def angle(v: np.ndarray) -> float:
        return float(np.degrees(abs(np.arctan2(v[1], v[0]))))

    raw, smooth = angle(end_offset(0.0)), angle(end_offset(0.02))
    assert smooth < 10.0, smooth
    assert smooth < raw, (smooth, raw)


def test_approach_shares_are_the_directrix_first_steps_to_the_first_point() -> None:
    s = np.array([0.0, 0.1, 0.3, 0.6, 1.0])
    np.testing.assert_allclose(approach_shares(s, 0.05), [1.0])  # about one section's step
    np.testing.assert_allclose(approach_shares(s, 0.19), [1.0])
    np.testing.assert_allclose(approach_shares(s, 0.3), [1 / 3, 1.0])
    np.testing.assert_allclose(approach_shares(s, 0.5), [1 / 6, 1 / 2, 1.0])  # nearest: 0.6
    np.testing.assert_allclose(approach_shares(s, 2.0), [0.1, 0.3, 0.6, 1.0])  # all of them, stretched


def _timed_arcs(n_demos: int = 5, n: int = 120) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    """Quarter circles with time stamps that start slowly and an orientation that turns."""
    from scipy.spatial.transform import Rotation

    u = np.linspace(0.0, 1.0, n)
    demos, stamps, quats = [], [], []
    for j in range(n_demos):
        theta = (np.pi / 2) * u**2  # from rest
        off = 0.02 * (j - 2)
        demos.append(np.column_stack([np.cos(theta) + off, np.sin(theta), 0.01 * np.cos(3 * theta + j)]))
        stamps.append(np.linspace(0.0, 2.0 + 0.1 * j, n))
        quats.append(Rotation.from_euler("z", (1.2 * u + 0.05 * j)[:, None]).as_quat())
    return demos, stamps, quats


def test_a_timed_start_behind_the_first_plane_approaches_at_the_section_times_and_turns_smoothly() -> None:
    demos, stamps, quats = _timed_arcs()
    canal = canal_core.fit(demos, timestamps=stamps, orientations=quats, n_samples=100)
    assert canal.section_times is not None and canal.orientation is not None
    start = canal.directrix[0] - 0.08 * canal.tangents[0]
    result = canal.reproduce_detailed(start, start_orientation=quats[0][0])
    m = result.approach
    assert m >= 3 and result.section_index == 0
    # Approach point i at section i's time; the ratio rule's path, from section 1 on, m
    # sections' time later than it would start without the approach.
    tau = canal.section_times - canal.section_times[0]
    np.testing.assert_allclose(result.times[1 : m + 1], tau[1 : m + 1], atol=1e-9)
    np.testing.assert_allclose(result.times[m + 1 :], tau[1:] + tau[m + 1] - tau[1], atol=1e-9)
    assert np.all(result.velocities[: m + 1] @ canal.tangents[0] > 0.0)
    # One orientation per position, turning from the start's to the first section's in the
    # approach's shares (no step larger than the turn itself).
    q = result.orientations
    assert q.shape == (result.positions.shape[0], 4)
    assert np.all(np.einsum("td,td->t", q[1:], q[:-1]) > 0.0)
    turn = canal_core.orientation.angles_between(q[0], q[m + 1])
    steps = canal_core.orientation.angles_between(q[1 : m + 2], q[: m + 1])
    assert steps.max() < turn / 2 + 1e-9
    # Not inside at first: the first inside point is counted after the approach.
    assert result.entry_index >= (0 if result.inside else m + 1)


def test_a_start_behind_the_first_plane_with_obstacles_flags_no_approach_point_as_a_detour() -> None:
    demos, stamps, _ = _timed_arcs()
    canal = canal_core.fit(demos, timestamps=stamps, n_samples=100)
    start = canal.directrix[0] - 0.08 * canal.tangents[0]
    ball = {"kind": "sphere", "center": canal.directrix[60].tolist(), "radius": 0.01}
    result = canal.reproduce_detailed(start, obstacles=[ball])
    m = result.approach
    assert m >= 3 and result.detoured is not None
    assert result.detoured.shape == (result.positions.shape[0] - 1,)
    assert not result.detoured[:m].any()
    assert result.times.shape == (result.positions.shape[0],)


def test_a_start_past_the_canal_end_or_far_beside_it_moves_no_faster_than_the_demonstrations() -> None:
    """Five demonstrations 1 m long in 2 s (0.5 m/s). A start 2 cm past the last plane was
    given one step to the end in 1 ns (2e7 m/s); one far away, a single step of 1.7 km; one
    beside the last sections, a landing at 6 m/s. Every step now takes at least the time the
    fastest demonstration needed for it, and an approach has at most one point per section."""
    canal = ring_canal()
    for start in ([1.02, 0.0, 0.0], [1.5, 0.0, 0.0], [1.0, 0.3, 0.0], [1000.0, 1000.0, 1000.0],
                  [0.99, 0.3, 0.0], [-1.0, 0.0, 0.0], [0.5, 0.3, 0.0]):
        result = canal.reproduce_detailed(start)
        speeds = np.linalg.norm(np.diff(result.positions, axis=0), axis=1) / np.diff(result.times)
        assert speeds.max() <= 0.5 * 1.5, start  # 0.5 m/s, within the demonstrations' own spread
        assert result.approach <= canal.n_sections, start
        assert np.linalg.norm(result.velocities, axis=1).max() <= 0.5 * 2.0, start


def test_many_points_on_a_fine_canal_are_located_in_bounded_memory() -> None:
    # contains/locate held a (points, sections) table: 20,000 points on a 5,000-section
    # canal took 2.6 GB. They are read a block of points at a time, to the same answer.
    x = np.linspace(0.0, 1.0, 400)
    demos = [np.column_stack([x, 0.1 * np.sin(np.pi * x) + dy, 0 * x + dz])
             for dy, dz in [(-0.03, 0.0), (0.03, 0.0), (0.0, -0.03), (0.0, 0.03)]]
    canal = canal_core.fit(demos, n_samples=5000)
    rng = np.random.default_rng(0)
    points = canal.directrix[rng.integers(0, 5000, 20000)] + 0.05 * rng.normal(size=(20000, 3))
    tracemalloc.start()
    try:
        inside = canal.contains(points)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 100e6, f"{peak / 1e6:.0f} MB"
    assert 0.0 < inside.mean() < 1.0
    few = rng.choice(20000, 40, replace=False)
    one_by_one = np.array([canal.contains(points[k : k + 1])[0] for k in few])
    assert np.array_equal(one_by_one, inside[few])
    loc, alone = canal.locate(points), canal.locate(points[few])
    np.testing.assert_array_equal(loc.index[few], alone.index)
    np.testing.assert_array_equal(loc.eta[few], alone.eta)
