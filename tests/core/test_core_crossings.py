"""plane_crossings (block search) against a dense reference of the same rule: the nearest
crossing in index within +-N/3, taken when within +-4 samples or nearer c_i than the demo's
sample nearest the plane within +-4; otherwise that sample projected onto the plane."""

from __future__ import annotations

import numpy as np
import pytest
from raw_logs import raw_demo_set

from canal_core import crossings
from canal_core.alignment import resampled_demonstrations
from canal_core.crossings import NEAR_WINDOW, plane_crossings
from canal_core.enclosing import bracketing_sections
from canal_core.frames import rotation_minimizing_frames, smoothed_curve
from canal_core.preprocess import prepared_demonstration


def dense_reference(aligned: np.ndarray, centres: np.ndarray, tangents: np.ndarray) -> np.ndarray:
    n, big_n, dim = aligned.shape
    wide = max(NEAR_WINDOW + 1, round(big_n / 3))
    out = np.zeros((big_n, n, dim))
    for i in range(big_n):
        for j in range(n):
            d = aligned[j] @ tangents[i] - centres[i] @ tangents[i]
            near = np.arange(max(0, i - NEAR_WINDOW), min(big_n, i + NEAR_WINDOW + 1))
            k = near[np.argmin(np.abs(d[near]))]
            fallback = aligned[j, k] - d[k] * tangents[i]
            reference = np.linalg.norm(aligned[j, k] - centres[i])
            best = None
            for s in range(max(0, i - wide), min(big_n - 2, i + wide - 1) + 1):
                if d[s] == 0.0 or np.sign(d[s]) != np.sign(d[s + 1]):
                    if best is None or abs(s + 0.5 - i) < abs(best + 0.5 - i):
                        best = s
            if best is None:
                out[i, j] = fallback
                continue
            a = d[best] / (d[best] - d[best + 1]) if d[best] != d[best + 1] else 0.0
            point = aligned[j, best] + np.clip(a, 0.0, 1.0) * (aligned[j, best + 1] - aligned[j, best])
            close = abs(best + 0.5 - i) <= NEAR_WINDOW
            out[i, j] = point if close or np.linalg.norm(point - centres[i]) <= reference else fallback
    return out


@pytest.mark.parametrize(("shape", "seed", "n_samples"), [("task1", 0, 120), ("helix", 1, 150), ("task2", 2, 97)])
def test_block_search_matches_the_dense_rule(shape: str, seed: int, n_samples: int) -> None:
    demos = [prepared_demonstration(g.positions, field="d")[0] for g in raw_demo_set(shape, seed, n_demos=4)]
    aligned = resampled_demonstrations(demos, [None] * 4, n_samples)
    centres = aligned.mean(axis=0)
    tangents, _, _ = rotation_minimizing_frames(smoothed_curve(centres, 0.02 * n_samples))
    fast = plane_crossings(aligned, centres, tangents, monotone=False)
    np.testing.assert_allclose(fast, dense_reference(aligned, centres, tangents), rtol=0, atol=1e-12)


@pytest.mark.parametrize(("block", "group"), [(2, 1), (2, 3), (5, 4), (16, 4)])
@pytest.mark.parametrize("seed", range(3))
def test_block_search_matches_the_dense_rule_on_looping_demos(
    seed: int, block: int, group: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Random walks that loop back: many crossings per plane, far ones, ties, and planes that
    # cut many blocks. Small blocks put a pair's crossings in different blocks (the per-pair
    # minimum across blocks); 16 puts several in one block (the minimum within a block).
    # Groups of 3 leave a partial last group.
    monkeypatch.setattr(crossings, "BLOCK", block)
    monkeypatch.setattr(crossings, "GROUP", group)
    rng = np.random.default_rng(seed)
    n_samples = 90
    base = np.cumsum(rng.normal(size=(n_samples, 3)), axis=0)
    aligned = np.stack([np.roll(base + rng.normal(scale=1.5, size=base.shape), k, axis=0) for k in (-12, 0, 7)])
    centres = aligned.mean(axis=0)
    tangents, _, _ = rotation_minimizing_frames(smoothed_curve(centres, 0.02 * n_samples))
    fast = plane_crossings(aligned, centres, tangents, monotone=False)
    np.testing.assert_allclose(fast, dense_reference(aligned, centres, tangents), rtol=0, atol=1e-12)


def nearest_bracket(sample: np.ndarray, approx: int, tangents: np.ndarray, plane: np.ndarray) -> int | None:
    d = tangents @ sample - plane
    pairs = [i for i in range(len(d) - 1) if d[i] == 0.0 or np.sign(d[i]) != np.sign(d[i + 1])]
    return min(pairs, key=lambda i: (abs(i - approx + 0.5), i)) if pairs else None


@pytest.mark.parametrize("seed", range(4))
def test_bracketing_shells_find_the_nearest_pair_of_planes(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(5, 60))
    tangents = rng.normal(size=(n, 3)) + [2.0, 0.0, 0.0]
    tangents /= np.linalg.norm(tangents, axis=1)[:, None]
    plane = np.einsum("nd,nd->n", rng.normal(size=(n, 3)), tangents)
    samples = 2.0 * rng.normal(size=(40, 3))
    approx = rng.integers(0, n, size=40)
    # The envelope's doubling: a window of 4, then shells (4, 8], (8, 16], ... to the whole canal.
    index, _, found = bracketing_sections(samples, approx, tangents, plane, 4)
    width = 4
    while width < n - 1:
        inner, width = width, min(2 * width, n - 1)
        shell = bracketing_sections(samples, approx, tangents, plane, width, inner)
        index = np.where(found, index, shell[0])
        found = found | shell[2]
    for k in range(40):
        expected = nearest_bracket(samples[k], int(approx[k]), tangents, plane)
        assert found[k] == (expected is not None)
        if expected is not None:
            assert index[k] == expected


def pressing_strokes(seed: int, n_demos: int = 6, n_rows: int = 300) -> list[np.ndarray]:
    """Down, up and down again (a press repeated beside the first), each demo pressing to
    its own depths at its own pace."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n_demos):
        u = np.linspace(0.0, 1.0, n_rows)
        w = u + rng.uniform(-0.08, 0.08) * np.sin(np.pi * u)
        first, second = rng.uniform(0.0, 0.04, size=2)
        knots = [0.0, 0.35, 0.5, 0.65, 1.0]
        z = np.interp(w, knots, [0.3, 0.05 + first, 0.15, 0.05 + second, 0.05 + second])
        x = np.interp(w, knots, [0.0, 0.2, 0.22, 0.24, 0.24]) + rng.normal(scale=0.005)
        y = np.full(n_rows, rng.normal(scale=0.01)) + 0.02 * w
        out.append(np.column_stack([x, y, z]))
    return out


@pytest.mark.parametrize("seed", range(3))
def test_a_stroke_that_folds_back_is_crossed_in_its_own_order(seed: int) -> None:
    # The nearest crossing in index of a plane at the bottom of the first press can be the
    # second press's (a shallower first press never reaches that plane): the sections then
    # mixed the two passes. Each demo's crossings must follow its own parameter.
    demos = pressing_strokes(seed)
    aligned = resampled_demonstrations(demos, [None] * len(demos), 200)
    centres = aligned.mean(axis=0)
    tangents, _, _ = rotation_minimizing_frames(smoothed_curve(centres, 0.02 * 200))
    plane = np.einsum("nd,nd->n", centres, tangents)
    _, unordered = crossings.located_crossings(aligned, centres, tangents, monotone=False)
    assert crossings.steps_back(unordered.T).any()  # the set folds: the old rule mixed passes
    points, index = crossings.located_crossings(aligned, centres, tangents)
    assert not crossings.steps_back(index.T).any()
    for j in range(len(demos)):
        met = index[:, j][np.isfinite(index[:, j])]
        # Consecutive met sections lie on the same or later segments of the demo.
        assert np.all(np.diff(np.floor(met)) >= 0.0)
    # Every point is on its plane, at the demo's own sample where it crossed there.
    np.testing.assert_allclose(np.einsum("njd,nd->nj", points, tangents) - plane[:, None], 0.0, atol=1e-12)
    for i, j in zip(*np.nonzero(np.isfinite(index)), strict=True):
        k = int(np.floor(index[i, j]))
        seg = aligned[j, k : k + 2]
        assert np.linalg.norm(points[i, j] - seg[0]) <= np.linalg.norm(seg[1] - seg[0]) + 1e-12


def test_the_heaviest_chain_is_in_order_and_takes_the_nearest_pass() -> None:
    # Sections 0..3; section 2 is met on its own pass (segment 2) and on the other (9);
    # section 3 on segment 3. The chain keeps 0, 1, 2 (its own pass), 3.
    sec = np.array([0, 1, 2, 2, 3])
    seg = np.array([0, 1, 2, 9, 3])
    weight = 1.0 - np.abs(seg - sec) / 20.0
    assert crossings._heaviest_chain(sec, seg, weight, 12).tolist() == [0, 1, 2, 4]
    # Section 1 met after section 2's only crossing: one of them is left out.
    seg = np.array([0, 5, 2, 2, 3])
    chain = crossings._heaviest_chain(sec, seg, 1.0 - np.abs(seg - sec) / 20.0, 12)
    assert chain.tolist() == [0, 2, 4]
