"""The fit's vectorised stages against straightforward (slow, loop-by-loop) versions of the
same rules, on generated raw logs and on random walks that loop and glitch.

Each fast stage prunes work with necessary conditions (a window whose path is short cannot
hold a glitch, a block whose ball the plane misses holds no crossing, ...); these tests
check that the pruning never changes an answer.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from raw_logs import raw_demo_set

from canal_core import glitches, preprocess
from canal_core.glitches import (
    CHORD_FACTOR,
    GLITCH_FLOOR,
    GLITCH_PASSES,
    GLITCH_SCALE_WINDOW,
    MAX_GLITCH_RUN,
    SPIKE_FACTOR,
    SPIKE_WINDOW,
    robust_path_length,
)
from canal_core.preprocess import NEAR_DUPLICATE_TOLERANCE, mask_of_new_samples

# ---- glitches (canal_core.glitches, step 4 of canal_core.preprocess) -----------------------


def slow_spike_mask(x: np.ndarray, floor: float) -> np.ndarray:
    """Step 4 as its docstring states it: every window, every interior sample, in Python
    (``floor``: GLITCH_FLOOR x the robust path length of the whole demonstration)."""
    n = x.shape[0]
    spike = np.zeros(n, dtype=bool)
    if n < 5:
        return spike
    steps = [float(np.linalg.norm(x[i + 1] - x[i])) for i in range(n - 1)]

    def median(width: int, at: int) -> float:
        width = min(width, len(steps))
        start = min(max(at - width // 2, 0), len(steps) - width)
        return sorted(steps[start : start + width])[width // 2]

    for m in range(1, min(MAX_GLITCH_RUN, n - 2) + 1):
        for a in range(0, n - m - 1):
            b = a + m + 1
            chord = float(np.linalg.norm(x[b] - x[a]))
            mid = 0.5 * (x[a] + x[b])
            if m == 1:
                step = median(2 * SPIKE_WINDOW + 1, a + 1)
            else:
                step = median(2 * GLITCH_SCALE_WINDOW + MAX_GLITCH_RUN + 1, (a + b) // 2)
            limit = SPIKE_FACTOR * 0.5 * (m + 1) * step
            for k in range(1, m + 1):
                dev = float(np.linalg.norm(x[a + k] - mid))
                if dev > CHORD_FACTOR * chord and dev > limit and dev > floor:
                    spike[a + k] = True
    width = 2 * SPIKE_WINDOW + 1
    spike[0] |= steps[0] > SPIKE_FACTOR * max(steps[1], median(width, 1)) * 2.0 and steps[0] > floor
    spike[-1] |= steps[-1] > SPIKE_FACTOR * max(steps[-2], median(width, n - 2)) * 2.0 and steps[-1] > floor
    return spike


def slow_glitch_mask(x: np.ndarray) -> np.ndarray:
    glitch = np.zeros(x.shape[0], dtype=bool)
    floor = GLITCH_FLOOR * robust_path_length(x)
    for _ in range(GLITCH_PASSES):
        left = np.flatnonzero(~glitch)
        found = slow_spike_mask(x[left], floor)
        if not found.any():
            break
        glitch[left[found]] = True
    return glitch


def glitch_inputs() -> list[np.ndarray]:
    """What the glitch step sees in a fit: raw logs without their repeats (still ends with
    sensor jitter, glitches spread by the poller), and short random walks with spikes."""
    cases = []
    for shape, seed in (("task1", 0), ("helix", 1), ("task2", 2)):
        for log in raw_demo_set(shape, seed, n_demos=2, rate_hz=60.0, n_glitches=2):
            pts = log.positions[mask_of_new_samples(log.positions)]
            keep = preprocess._repeat_mask(pts, NEAR_DUPLICATE_TOLERANCE * robust_path_length(pts))
            cases.append(pts[keep])
    # Logs resampled by rows (as the 1,000-row logs were): a glitch becomes a plateau
    # with ramps, found over two or three passes.
    for shape, seed in (("task1", 3), ("lasa:Sshape", 4)):
        for log in raw_demo_set(shape, seed, n_demos=2, rate_hz=120.0, n_glitches=2):
            x = np.linspace(0.0, log.positions.shape[0] - 1.0, 700)
            rows = np.column_stack([np.interp(x, np.arange(log.positions.shape[0]), log.positions[:, d]) for d in range(3)])
            pts = rows[mask_of_new_samples(rows)]
            keep = preprocess._repeat_mask(pts, NEAR_DUPLICATE_TOLERANCE * robust_path_length(pts))
            cases.append(pts[keep])
    rng = np.random.default_rng(7)
    for _ in range(40):
        n = int(rng.integers(5, 40))
        walk = np.cumsum(rng.normal(size=(n, 3)), axis=0)
        hit = rng.integers(0, n, size=int(rng.integers(0, 4)))
        walk[hit] += rng.normal(scale=15.0, size=(hit.size, 3))
        cases.extend([walk, walk[:, :2].copy()])
    return cases


def test_glitch_mask_matches_the_rule_window_by_window() -> None:
    flagged = later_passes = 0
    for x in glitch_inputs():
        fast = glitches.glitch_mask(x)
        np.testing.assert_array_equal(fast, slow_glitch_mask(x))
        flagged += int(fast.sum())
        later_passes += int(fast.sum() > glitches.spike_mask(x).sum())
    # The comparison saw glitches, and glitches that only a later pass (re-testing the
    # stretches around what the first one removed) finds.
    assert flagged > 20
    assert later_passes >= 2



@pytest.mark.parametrize("batch_rows", [1, glitches.SPIKE_BATCH_ROWS, 1 << 30])
def test_batched_glitch_masks_equal_each_demo_alone(batch_rows: int, monkeypatch: pytest.MonkeyPatch) -> None:
    # One pass over several demonstrations at once (windows must not reach into the next
    # demo, arc lengths restart, medians are clipped to their own demo) gives each demo
    # the slow rule's verdicts. Groups mix long demos with short ones (below
    # BATCHED_SPIKE_MIN they go one at a time) and demos with no glitch with demos whose
    # glitches need the later passes; batches of one part, of the default rows, of all.
    monkeypatch.setattr(glitches, "SPIKE_BATCH_ROWS", batch_rows)
    cases = glitch_inputs()
    rng = np.random.default_rng(11)
    groups = [cases[k : k + 5] for k in range(0, len(cases), 5)]
    groups += [[cases[int(k)] for k in rng.choice(len(cases), size=4, replace=False)] for _ in range(6)]
    flagged = 0
    for group in groups:
        for dim in (2, 3):
            parts = [x for x in group if x.shape[1] == dim]
            if not parts:
                continue
            for x, fast in zip(parts, glitches.glitch_masks(parts), strict=True):
                np.testing.assert_array_equal(fast, slow_glitch_mask(x))
                flagged += int(fast.sum())
    assert flagged > 20


def test_prepared_samples_many_fails_where_one_at_a_time_fails_first() -> None:
    # The batched preparation raises the error of the first demo that fails, whichever
    # stage it fails in: here demo 1 fails late (it only stands still) and demo 2 early
    # (identical points), so demo 1 is named; without demo 1, demo 2 is.
    from canal_core.errors import InvalidInputError
    from canal_core.preprocess import prepared_samples, prepared_samples_many

    logs = [g.positions for g in raw_demo_set("task1", 4, n_demos=3)]
    # Two still clusters: it moves, yet only 2 samples are left once the still ends go.
    still = np.array([[0.0, 0.0, 0.0], [1e-7, 0.0, 0.0], [2e-7, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0 + 1e-7, 0.0, 0.0], [1.0 + 2e-7, 0.0, 0.0]])
    identical = np.ones((20, 3))
    names = ["demos[0]", "demos[1]", "demos[2]"]
    for demos, expected in (([logs[0], still, identical], "demos[1]"), ([logs[0], logs[1], identical], "demos[2]")):
        one_by_one = None
        try:
            for d, name in zip(demos, names, strict=True):
                prepared_samples(d, None, field=name)
        except InvalidInputError as error:
            one_by_one = error
        assert one_by_one is not None and one_by_one.field == expected
        try:
            prepared_samples_many(demos, [None] * 3, names, names)
        except InvalidInputError as error:
            assert error.field == expected
            assert str(error) == str(one_by_one)
        else:
            raise AssertionError("prepared_samples_many accepted a demo prepared_samples refuses")
    good = prepared_samples_many(logs, [None] * 3, names, names)
    for d, name, p in zip(logs, names, good, strict=True):
        alone = prepared_samples(d, None, field=name)
        np.testing.assert_array_equal(p.rows, alone.rows)
        np.testing.assert_array_equal(p.sample_rows, alone.sample_rows)
        np.testing.assert_array_equal(p.sample_phase, alone.sample_phase)


@st.composite
def raw_demo(draw: st.DrawFn, dim: int) -> np.ndarray:
    """One raw demo as the glitch test can meet it: a random walk, a smooth curve or a line
    walked out and back (a genuine reversal), through 3 to 200 positions (short demos clip
    their windows), with glitch runs of 1..8 samples (plateaus or ramps, one pass or several to
    remove), exact and rounding-level repeats, and jittering still ends."""
    n = draw(st.one_of(st.integers(3, 20), st.integers(3, 200)))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    kind = draw(st.sampled_from(["walk", "smooth", "reversal"]))
    if kind == "walk":
        x = np.cumsum(rng.normal(size=(n, dim)), axis=0)
    elif kind == "smooth":
        t = np.linspace(0.0, 1.0, n)[:, None]
        x = np.sin(t * rng.uniform(1.0, 6.0, size=dim) + rng.uniform(0.0, 3.0, size=dim))
    else:
        u = 1.0 - np.abs(np.linspace(-1.0, 1.0, n))[:, None]
        x = u * rng.normal(size=dim) + 1e-3 * rng.normal(size=(n, dim))
    step = float(np.median(np.linalg.norm(np.diff(x, axis=0), axis=1))) if n > 1 else 1.0
    # Repeats: each row shown 1..3 times, some copies off at rounding level.
    shown = rng.integers(1, 4, size=n) if draw(st.booleans()) else np.ones(n, dtype=int)
    x = np.repeat(x, shown, axis=0)
    nudged = rng.random(x.shape[0]) < 0.2
    x[nudged] += 1e-13 * step * rng.normal(size=(int(nudged.sum()), dim))
    head, tail = draw(st.sampled_from([0, 2, 30])), draw(st.sampled_from([0, 2, 30]))
    still = 1e-4 * step * rng.normal(size=(head + tail, dim))
    x = np.vstack([x[:1] + still[:head], x, x[-1:] + still[head:]])
    # Glitch runs anywhere, and at the very ends (a reading lost as the logger starts).
    rows = x.shape[0]
    for _ in range(draw(st.integers(0, 4))):
        at = draw(st.one_of(st.integers(0, 3), st.integers(0, rows - 1), st.integers(rows - 4, rows - 1)))
        at, m = min(max(at, 0), rows - 1), draw(st.integers(1, 8))
        height = draw(st.floats(0.5, 80.0)) * step
        direction = rng.normal(size=dim)
        profile = np.ones(m) if draw(st.booleans()) else 1.0 - np.abs(np.linspace(-0.8, 0.8, m))
        x[at : at + m] += height * profile[: rows - at, None] * direction / np.linalg.norm(direction)
    # Units from millimetres to kilometres: demos of one set differ in size, so a window
    # or a median that strays into the next demo meets steps of another scale.
    return 10.0 ** draw(st.integers(-3, 3)) * x


@st.composite
def raw_demo_sets(draw: st.DrawFn) -> list[np.ndarray]:
    dim = draw(st.sampled_from([2, 3]))
    demos = draw(st.lists(raw_demo(dim), min_size=1, max_size=6))
    # Demos recorded back to back start where the previous one ended: concatenated, the
    # window from one demo's tail to the next one's head is then short enough to pass the
    # window test, which only the part bounds keep out.
    for j in range(1, len(demos)):
        if draw(st.booleans()):
            demos[j] = demos[j] - demos[j][0] + demos[j - 1][-1]
    return demos


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(demos=raw_demo_sets())
def test_one_demo_and_many_demo_paths_agree(demos: list[np.ndarray]) -> None:
    # The one-demo path (a lone part: no part bounds to respect, tested in place) and the
    # many-demo path (parts concatenated, windows and medians kept inside their own part)
    # share the rule but not its bookkeeping: a window reaching into the next demo, a median
    # borrowing its steps, or an arc length that does not restart would show here, against
    # each other and against the rule written window by window.
    alone = [glitches.glitch_mask(x) for x in demos]
    for x, batched, single in zip(demos, glitches.glitch_masks(demos), alone, strict=True):
        np.testing.assert_array_equal(batched, single)
        np.testing.assert_array_equal(single, slow_glitch_mask(x))
    # The whole stage: the same rows and phases, or the same first error.
    from canal_core.errors import InvalidInputError
    from canal_core.preprocess import prepared_samples, prepared_samples_many

    names = [f"demos[{j}]" for j in range(len(demos))]
    expected: list[preprocess.PreparedDemonstration] = []
    first_error: InvalidInputError | None = None
    for x, name in zip(demos, names, strict=True):
        try:
            expected.append(prepared_samples(x, None, field=name))
        except InvalidInputError as error:
            first_error = error
            break
    try:
        got = prepared_samples_many(demos, [None] * len(demos), names, names)
    except InvalidInputError as error:
        assert first_error is not None, f"the many-demo path refused what each passes alone: {error}"
        assert (error.field, str(error)) == (first_error.field, str(first_error))
        return
    assert first_error is None, f"the many-demo path accepted what one demo refuses: {first_error}"
    for p, q in zip(got, expected, strict=True):
        for field in ("rows", "positions", "sample_rows", "sample_phase"):
            np.testing.assert_array_equal(getattr(p, field), getattr(q, field))


# ---- alignment: every demo's spline in one stacked solve -----------------------------------


def test_stacked_splines_equal_scipys_spline_per_demo() -> None:
    # The stacked solve must give scipy's numbers bit for bit (a coupling entry left
    # non-zero, or a not-a-knot row of the wrong demo, shows up in the first bits), on
    # prepared raw logs by arc length and by time, short demos (4-6 knots, the smallest
    # the stacked path takes) and a set with a 3-knot demo (scipy's parabola).
    from scipy.interpolate import CubicSpline

    from canal_core.alignment import spline_knots, stacked_spline_values
    from canal_core.preprocess import prepared_samples

    rng = np.random.default_rng(5)
    sets: list[list[tuple[np.ndarray, np.ndarray]]] = []
    for shape in ("task1", "helix"):
        prepared = [prepared_samples(g.positions, g.timestamps, field="d") for g in raw_demo_set(shape, 2)]
        sets.append([spline_knots(p.positions, None) for p in prepared])
        sets.append([spline_knots(p.positions, p.timestamps) for p in prepared])
    for dim in (2, 3):
        walks = [rng.normal(size=(k, dim)).cumsum(axis=0) for k in (4, 5, 6, 40)]
        sets.append([spline_knots(w, np.cumsum(rng.uniform(0.1, 1.0, w.shape[0]))) for w in walks])
    sets.append([spline_knots(rng.normal(size=(k, 3)), None) for k in (3, 7)])
    for knots in sets:
        for at in (np.linspace(0.0, 1.0, 1000), np.linspace(0.0, 1.0, 7), rng.uniform(0.0, 1.0, 50)):
            stacked = stacked_spline_values([k for k, _ in knots], [v for _, v in knots], at)
            for j, (k, v) in enumerate(knots):
                np.testing.assert_array_equal(stacked[j], CubicSpline(k, v, axis=0)(at))
