"""The "warp" alignment: DTW onto the mean on a few samples, its banded kernel, and what it
aligns that the clock alone does not."""

from __future__ import annotations

import numpy as np
import pytest

import canal_core
from canal_core.alignment import DTW_SAMPLES, dtw_parameters, resampled_demonstrations, splines_at
from canal_core.warping import banded_mean_matches, dtw_path, mean_matched_index


@pytest.mark.parametrize(("n", "m", "band"), [(40, 40, 4), (64, 64, 6), (50, 80, 8), (80, 50, 5), (30, 30, 1)])
@pytest.mark.parametrize("seed", range(3))
def test_the_banded_kernel_matches_the_full_table_path(n: int, m: int, band: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    a = np.cumsum(rng.normal(size=(n, 3)), axis=0)
    b = np.cumsum(rng.normal(size=(m, 3)), axis=0)
    got = banded_mean_matches(a, b[None], band)[0]
    np.testing.assert_allclose(got, mean_matched_index(*dtw_path(a, b, band=band), n))


@pytest.mark.parametrize(("n", "m", "band"), [(64, 64, 6), (50, 80, 8), (80, 50, 5)])
def test_the_batched_kernel_matches_each_path(n: int, m: int, band: int) -> None:
    rng = np.random.default_rng(n + m)
    a = np.cumsum(rng.normal(size=(n, 3)), axis=0)
    curves = np.cumsum(rng.normal(size=(4, m, 3)), axis=1)
    got = banded_mean_matches(a, curves, band)
    for c in range(4):
        ia, ib = dtw_path(a, curves[c], band=band)
        np.testing.assert_allclose(got[c], np.bincount(ia, weights=ib, minlength=n) / np.bincount(ia, minlength=n))


def paced(pace: float, n_rows: int = 400) -> np.ndarray:
    """One path (a bump then a turn), travelled with a pace that hurries (pace > 0) or
    dawdles (< 0) in its first half; samples evenly in time."""
    t = np.linspace(0.0, 1.0, n_rows)
    u = t + pace * np.sin(np.pi * t) ** 2 * (1.0 - t)
    u = (u - u[0]) / (u[-1] - u[0])
    return np.column_stack([u, 0.3 * np.exp(-((u - 0.3) / 0.08) ** 2), 0.2 * np.sin(2.0 * np.pi * u) * u])


def test_warp_aligns_one_path_at_different_paces() -> None:
    # The same path at four paces: aligned by the index clock alone, the demos' samples of one
    # section are different places; warped onto their mean they nearly coincide.
    demos = [paced(p) for p in (-0.4, -0.1, 0.2, 0.5)]
    stamps: list[np.ndarray | None] = [np.arange(d.shape[0], dtype=np.float64) for d in demos]
    clock = resampled_demonstrations(demos, stamps, 300)
    warped = splines_at(demos, stamps, dtw_parameters(demos, stamps, 300, resolution=DTW_SAMPLES))
    def spread(aligned: np.ndarray) -> np.ndarray:
        return np.asarray(np.linalg.norm(aligned - aligned.mean(axis=0), axis=2))

    # Within the band (a tenth of the motion) the warp takes up the pace; the worst sections
    # lie where the paces differ by more than that.
    assert np.median(spread(warped)) < 0.5 * np.median(spread(clock))
    assert spread(warped).max() < spread(clock).max()
    # Matched on DTW_SAMPLES samples, interpolated to 300: parameters rise from 0 to 1.
    parameters = dtw_parameters(demos, stamps, 300, resolution=DTW_SAMPLES)
    assert parameters.shape == (4, 300)
    assert np.all(np.diff(parameters, axis=1) > 0.0)
    np.testing.assert_allclose(parameters[:, [0, -1]], [[0.0, 1.0]] * 4)


def test_warp_is_the_default_and_its_canal_holds_every_sample() -> None:
    demos = [paced(p) + 0.01 * k for k, p in enumerate((-0.4, -0.1, 0.2, 0.5))]
    canal = canal_core.fit(demos, n_samples=500)
    assert canal.options.alignment == "warp"
    assert canal.contains(np.vstack(demos)).all()
    assert canal_core.Canal.from_dict(canal.to_dict()).options.alignment == "warp"
