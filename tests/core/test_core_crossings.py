"""plane_crossings (block search) against a dense reference of the same rule: the nearest
crossing in index within +-N/3, taken when within +-4 samples or nearer c_i than the demo's
sample nearest the plane within +-4; otherwise that sample projected onto the plane."""

from __future__ import annotations

import numpy as np
import pytest
from raw_logs import raw_demo_set

from canal_core.alignment import resampled_demonstrations
from canal_core.crossings import NEAR_WINDOW, plane_crossings
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
    fast = plane_crossings(aligned, centres, tangents)
    np.testing.assert_allclose(fast, dense_reference(aligned, centres, tangents), rtol=0, atol=1e-12)
