"""Raw robot logs in, nothing breaks: the preparation stage, property tests over
generated raw logs, the real UR5e demos, and the exact inputs that crashed before."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from raw_logs import raw_demo_set, raw_log, shape_curves, ur5e_demos

import canal_core
from canal_core import CanalError, InvalidInputError
from canal_core.alignment import demonstration_spline, dtw_aligned_demonstrations
from canal_core.crossings import plane_crossings
from canal_core.preprocess import (
    prepared_demonstration,
    prepared_rows,
    prepared_samples,
    size_ratios,
)

NON_LASA = ["task1", "task2", "helix"]


def arc_demos(n: int = 80) -> list[np.ndarray]:
    u = np.linspace(0.0, 1.0, n)
    return [np.column_stack([u, 0.2 * np.sin(np.pi * u) + dy, 1e-3 + 0.0 * u]) for dy in (-0.02, 0.0, 0.02)]


def with_rounding_repeats(demo: np.ndarray, step: float) -> np.ndarray:
    """Every row followed by a copy that differs by ``step`` in z (z is ~1e-3, so steps as
    small as 1e-17 are representable but vanish in the cumulative arc length)."""
    copy = demo.copy()
    copy[:, 2] += step
    return np.stack([demo, copy], axis=1).reshape(-1, demo.shape[1])


# ---- regression: the exact inputs of the issue ---------------------------------------------


@pytest.mark.parametrize("step", [1e-17, 1e-15, 1e-12, 1e-9, 1e-7])
@pytest.mark.parametrize("alignment", ["spline", "dtw"])
def test_rounding_level_steps_fit(step: float, alignment: str) -> None:
    # Crashed with scipy's "x must be strictly increasing sequence" (an escaping ValueError).
    demos = [with_rounding_repeats(d, step) for d in arc_demos()]
    canal = canal_core.fit(demos, alignment=alignment, n_samples=100)
    assert np.isfinite(canal.radii).all()
    assert canal.contains(np.vstack(demos)).mean() > 0.95


def test_rounding_level_steps_on_the_by_time_path() -> None:
    # by_time with one demo lacking timestamps falls back to arc length for it: it crashed.
    demos = [with_rounding_repeats(d, 1e-17) for d in arc_demos()]
    times = [np.arange(d.shape[0]) * 0.01 for d in demos]
    times[1] = None  # type: ignore[call-overload]
    canal = canal_core.fit(demos, timestamps=times, n_samples=100)
    assert np.isfinite(canal.directrix).all()


def test_polling_stamps_on_the_by_time_path() -> None:
    # A polling logger stamps repeated rows alike: refused as "not strictly increasing" before.
    demos = arc_demos()
    times = []
    for d in demos:
        t = np.arange(d.shape[0]) * 0.01
        t[1::4] = t[0::4][: t[1::4].size]
        times.append(t)
    canal = canal_core.fit(demos, timestamps=times, n_samples=100)
    assert canal.contains(np.vstack(demos)).mean() > 0.95


def test_huge_finite_coordinates_are_refused_naming_the_demo() -> None:
    demos = arc_demos()
    demos[1] = demos[1] * 1e306
    with pytest.raises(InvalidInputError) as err:
        canal_core.fit(demos)
    assert err.value.field == "demos[1]" and "1e+15" in str(err.value)


def test_identical_points_are_refused_naming_the_demo() -> None:
    demos = [*arc_demos(), np.full((10, 3), 0.25)]
    with pytest.raises(InvalidInputError) as err:
        canal_core.fit(demos)
    assert err.value.field == "demos[3]" and "all 10 samples are identical" in str(err.value)


def test_rounding_level_motion_is_refused() -> None:
    wobble = 1.0 + np.random.default_rng(0).integers(0, 3, size=(30, 3)) * np.finfo(float).eps
    with pytest.raises(InvalidInputError, match="rounding level") as err:
        canal_core.fit([*arc_demos(), wobble])
    assert err.value.field == "demos[3]"


# ---- the preparation stage -----------------------------------------------------------------


def test_prepared_rows_are_input_rows_and_arc_length_strictly_increases() -> None:
    log = raw_demo_set("task1", seed=1, n_demos=1, rate_hz=1000.0)[0]
    rows = prepared_rows(log.positions, field="demos[0]")
    positions, times = prepared_demonstration(log.positions, field="demos[0]")
    assert times is None and np.array_equal(positions, log.positions[rows])
    assert np.all(np.diff(rows) > 0)
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    s = np.cumsum(steps) / steps.sum()
    assert np.all(np.diff(s) > 0) and steps.min() > 1e-7 * steps.sum()
    assert not np.isin(rows, log.glitch_rows).any()
    demonstration_spline(positions, None)  # scipy accepts the parameter


def test_glitches_are_dropped_and_still_ends_trimmed() -> None:
    rng = np.random.default_rng(3)
    curve = shape_curves("helix", 1, rng)[0]
    log = raw_log(curve, rng, rate_hz=300.0, n_glitches=2, still_seconds=(2.0, 2.0), move_seconds=3.0)
    prepared = prepared_samples(log.positions, log.timestamps, field="d")
    assert log.glitch_rows.size and not np.isin(prepared.rows, log.glitch_rows).any()
    assert not np.isin(prepared.sample_rows, log.glitch_rows).any()
    t = prepared.timestamps
    assert t is not None and np.all(np.diff(t) > 0)
    # The kept part starts at most one sample before the motion (2 s) and ends just after it.
    assert 1.9 < t[0] + 2 / 300 and t[-1] < 5.1 + 2 / 300
    assert prepared.sample_phase.min() == 0.0 and prepared.sample_phase.max() == 1.0


def test_a_genuine_reversal_is_not_a_glitch() -> None:
    # Out and back along one line (a poke): the apex is one sample, but it is real.
    u = np.concatenate([np.linspace(0, 1, 40), np.linspace(1, 0, 40)[1:]])
    poke = np.column_stack([u, 0 * u, 0 * u])
    rows = prepared_rows(poke, field="d")
    assert 39 in rows


def test_out_of_order_stamps_are_repaired_or_refused() -> None:
    x = np.linspace(0, 1, 40)
    demo = np.column_stack([x, np.sin(3 * x), 0 * x])
    t = np.linspace(0, 4, 40)
    late = t.copy()
    late[20] = late[5]  # one late packet
    early = t.copy()
    early[20] = 100.0  # one stamp from the future
    for stamps, lost in ((late, 20), (early, 20)):
        positions, times = prepared_demonstration(demo, stamps, field="d")
        assert times is not None and np.all(np.diff(times) > 0) and demo[lost].tolist() not in positions.tolist()
    reset = np.concatenate([t[:20], t[20:] - 3.0])
    with pytest.raises(InvalidInputError, match="sample 20") as err:
        prepared_demonstration(demo, reset, field="demos[4]", time_field="timestamps[4]")
    assert err.value.field == "timestamps[4]"


def test_dtw_warp_is_strictly_increasing() -> None:
    demos = [d for d in arc_demos()]
    demos[0] = np.vstack([demos[0][:1].repeat(1, axis=0), demos[0]])
    aligned = dtw_aligned_demonstrations([prepared_demonstration(d, field="d")[0] for d in demos], [None] * 3, 60)
    assert np.isfinite(aligned).all()


# ---- property tests over generated raw logs ------------------------------------------------


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    shape=st.sampled_from(NON_LASA),
    seed=st.integers(0, 2**31 - 1),
    n_demos=st.integers(2, 5),
    by_time=st.booleans(),
    alignment=st.sampled_from(["spline", "dtw"]),
    kind=st.sampled_from(["circle", "mec"]),
    data=st.data(),
)
def test_raw_logs_fit_or_fail_cleanly_and_reproductions_stay_inside(
    shape: str, seed: int, n_demos: int, by_time: bool, alignment: str, kind: str, data: st.DataObject
) -> None:
    logs = raw_demo_set(shape, seed, n_demos=n_demos, move_seconds=2.0, still_seconds=(1.0, 1.0),
                        rate_hz=float(data.draw(st.sampled_from([30.0, 120.0, 400.0]))))
    demos = [g.positions for g in logs]
    times = [g.timestamps for g in logs] if by_time else None
    try:
        canal = canal_core.fit(demos, timestamps=times, alignment=alignment, cross_section=kind, n_samples=80)
    except CanalError as exc:  # allowed, but it must name what is at fault
        assert exc.field, exc
        return
    i = data.draw(st.integers(0, canal.n_sections - 2))
    eta = data.draw(st.floats(0.0, 0.95))
    angle = data.draw(st.floats(0.0, 2 * np.pi))
    direction = np.array([np.cos(angle), np.sin(angle)])
    reach = canal_core.cross_sections.boundary_distance(canal.sections, np.array([i]), direction[None])[0]
    start = canal.directrix[i] + eta * reach * np.einsum("k,kd->d", direction, canal.basis[i])
    assert canal.contains(start[None])[0]
    path = canal.reproduce(start)
    assert np.isfinite(path).all()
    assert canal.contains(path).all()


@settings(max_examples=25, deadline=None)
@given(
    positions=st.lists(
        st.tuples(*[st.floats(-1e300, 1e300, allow_nan=False) | st.sampled_from([0.0, 1e-300, 1.0])] * 3),
        min_size=4, max_size=30,
    ),
)
def test_any_finite_demo_is_prepared_or_refused_naming_it(positions: list[tuple[float, ...]]) -> None:
    demo = np.asarray(positions, dtype=np.float64)
    try:
        canal = canal_core.fit([demo, demo[::-1].copy() + 0.0], n_samples=20)
    except CanalError as exc:
        assert exc.field, exc
    else:
        assert np.isfinite(canal.directrix).all()


# ---- the real UR5e demonstrations (tests/data, MIT) ------------------------------------------


def test_ur5e_demos_fit_in_every_alignment_and_hold_reproductions() -> None:
    positions, times, _ = ur5e_demos()
    for kwargs in ({}, {"timestamps": times}, {"alignment": "dtw"}):
        canal = canal_core.fit(positions, n_samples=200, **kwargs)  # type: ignore[arg-type]
        start = canal.directrix[0] + 0.5 * canal.radii[0] * canal.normals[0]
        path = canal.reproduce(start)
        assert canal.contains(path).all()
        assert np.linalg.norm(path[-1] - canal.directrix[-1]) < 0.5 * canal.radii[-1] + 1e-9


def test_ur5e_leave_one_out_reproductions_end_near_the_held_out_goal() -> None:
    positions, _, _ = ur5e_demos()
    for held in range(len(positions)):
        train = [p for j, p in enumerate(positions) if j != held]
        canal = canal_core.fit(train, n_samples=200)
        result = canal.reproduce_detailed(positions[held][0])
        assert np.isfinite(result.positions).all()
        # A start outside enters the canal over the entry blend (10 % of its length) and
        # stays inside from there on; a start inside never leaves (its approach included,
        # when it lies behind the first plane).
        if result.inside:
            assert canal.contains(result.positions).all()
        path = result.section_path
        assert canal.contains(path[0 if result.inside else path.shape[0] // 5 :]).all()
        # The demos all end within a few cm of one another (a reach to one target).
        assert np.linalg.norm(result.positions[-1] - positions[held][-1]) < 0.1


def test_ur5e_prepared_demos_drop_the_still_ends() -> None:
    positions, times, _ = ur5e_demos()
    for j, (p, t) in enumerate(zip(positions, times, strict=True)):
        prepared = prepared_samples(p, t, field=f"demos[{j}]")
        assert 100 < prepared.rows.size < p.shape[0]
        assert np.all(np.diff(prepared.timestamps) > 0)  # type: ignore[arg-type]


def test_plane_crossings_on_ur5e_lie_in_their_planes() -> None:
    positions, _, _ = ur5e_demos()
    canal = canal_core.fit(positions, n_samples=300)
    aligned = np.stack([d for d in canal_core.alignment.resampled_demonstrations(
        [prepared_demonstration(p, field="d")[0] for p in positions], [None] * 5, 300)])
    points = plane_crossings(aligned, canal.directrix, canal.tangents)
    offset = np.einsum("ijd,id->ij", points - canal.directrix[:, None, :], canal.tangents)
    assert np.abs(offset).max() < 1e-9


@settings(max_examples=40, deadline=None)
@given(
    n=st.integers(4, 40),
    stamps=st.lists(st.floats(-1e12, 1e12, allow_nan=False) | st.sampled_from([0.0, 1.0, 1.0 + 2e-16]), min_size=40, max_size=40),
    seed=st.integers(0, 2**16),
)
def test_any_finite_timestamps_are_repaired_or_refused_naming_them(n: int, stamps: list[float], seed: int) -> None:
    rng = np.random.default_rng(seed)
    u = np.linspace(0.0, 1.0, n)
    demo = np.column_stack([u, np.sin(3 * u), 0.1 * u]) + 1e-3 * rng.standard_normal((n, 3))
    times = np.asarray(stamps[:n])
    try:
        canal = canal_core.fit([demo, demo + 0.01], timestamps=[times, np.linspace(0, 1, n)], n_samples=30)
    except CanalError as exc:
        assert exc.field in ("demos[0]", "timestamps[0]"), exc
    else:
        assert np.isfinite(canal.directrix).all()


def test_a_glitch_spread_by_row_resampling_is_dropped_with_its_ramps() -> None:
    # A glitch repeated by the poller, then the log linearly resampled by rows (as the issue's
    # 1,000-row logs were): the glitch becomes a plateau with ramps; it used to stay in and
    # shift the demo's arc-length phase.
    u = np.linspace(0.0, 1.0, 300)
    demo = np.column_stack([0.6 * u, 0.05 * np.sin(np.pi * u), 0.0 * u])
    demo[150:154] = demo[150] + np.array([0.1, -0.13, -0.15])  # one reading, polled 4 times
    x = np.linspace(0.0, demo.shape[0] - 1.0, 560)
    resampled = np.column_stack([np.interp(x, np.arange(demo.shape[0]), demo[:, d]) for d in range(3)])
    positions, _ = prepared_demonstration(resampled, field="d")
    off_path = np.abs(positions[:, 2]) > 1e-9
    assert not off_path.any(), positions[off_path]


def slow_demo_with_dip(dy: float = 0.0) -> np.ndarray:
    """A 0.5 m reach in metres, slowing to a tenth of a millimetre per sample near its end,
    where the arm dips 1.5 mm and comes back over three samples (a kinesthetic demo's touch)."""
    u = np.linspace(0.0, 1.0, 600)
    s = u**2 * (3.0 - 2.0 * u)  # slow at both ends
    demo = np.column_stack([0.5 * s, 0.08 * np.sin(np.pi * s) + dy, 0.0 * s])
    steps = np.linalg.norm(np.diff(demo, axis=0), axis=1)
    at = int(np.flatnonzero(steps > 1e-4)[-1])  # the last sample still moving 0.1 mm a step
    demo[at - 1 : at + 2, 2] -= np.array([0.75e-3, 1.5e-3, 0.75e-3])
    return demo


def test_a_millimetre_dip_in_slow_motion_is_kept_and_a_5_cm_spike_dropped() -> None:
    # The dip is several local steps deep and off its chord, as a glitch is, but far below
    # GLITCH_FLOOR of the path: dropped, it could lie outside the canal fitted without it.
    demo = slow_demo_with_dip()
    dip = np.flatnonzero(demo[:, 2] < 0.0)
    spike_at = 300
    demo[spike_at] += np.array([0.0, 0.03, 0.04])  # one reading 5 cm off
    rows = prepared_rows(demo, field="d")
    assert np.isin(dip, rows).all(), dip[~np.isin(dip, rows)]
    assert spike_at not in rows
    # Every kept sample, the dip's included, is inside the canal fitted on it.
    demos = [demo] + [slow_demo_with_dip(dy) for dy in (-0.01, 0.01)]
    canal = canal_core.fit(demos)
    assert canal.contains(demo[rows]).all()


def test_a_demo_and_its_reverse_are_refused_naming_the_demos() -> None:
    # Found by the property test above: the mean of a path and its reverse stands still.
    demo = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    with pytest.raises(canal_core.DegenerateCanalError) as info:
        canal_core.fit([demo, demo[::-1].copy()], n_samples=20)
    assert info.value.field == "demos"


def test_size_ratios_single_out_a_demonstration_in_other_units() -> None:
    demos = arc_demos()
    assert np.allclose(size_ratios(demos), 1.0, atol=0.05)
    ratios = size_ratios([*demos, demos[0] * 1000.0])
    assert ratios[-1] == pytest.approx(1000.0, rel=0.05) and np.all(ratios[:-1] < 1.05)
    # the UR5e demos differ in size, not in units
    ur5e = size_ratios(ur5e_demos()[0])
    assert np.all((ur5e > 0.2) & (ur5e < 5.0)), ur5e
    # still demonstrations have no size; nothing is singled out
    assert size_ratios([np.zeros((5, 3)), np.zeros((5, 3))]).tolist() == [1.0, 1.0]
