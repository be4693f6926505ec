"""Frames are orthonormal, right-handed and continuous; Frenet is kept only for comparison."""

from __future__ import annotations

import numpy as np
import pytest

from canal_core import datasets, frames
from canal_core.frames import (
    frenet_frames,
    planar_frames,
    rotation_minimizing_frames,
    smoothed_curve,
)


def assert_orthonormal(t: np.ndarray, n: np.ndarray, b: np.ndarray) -> None:
    for v in (t, n, b):
        np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1.0, atol=1e-12)
    assert np.abs(np.einsum("ij,ij->i", t, n)).max() < 1e-12
    assert np.abs(np.einsum("ij,ij->i", t, b)).max() < 1e-12
    np.testing.assert_allclose(np.cross(t, n), b, atol=1e-12)  # right-handed


def curves() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(7)
    s = np.linspace(0, 1, 300)
    straight = np.column_stack([s, 2 * s, -s])
    arc = np.column_stack([np.cos(np.pi * s), np.sin(np.pi * s), 0 * s])
    noisy = datasets.helix(400) + 0.002 * rng.standard_normal((400, 3))
    s_line = np.column_stack([s, np.sin(4 * np.pi * s) * 0.2, 0 * s])  # inflections
    return {"straight": straight, "arc": arc, "helix": datasets.helix(400), "noisy": noisy, "s-curve": s_line}


@pytest.mark.parametrize("name", list(curves()))
def test_rmf_is_orthonormal_and_continuous(name: str) -> None:
    t, n, b = rotation_minimizing_frames(curves()[name])
    assert_orthonormal(t, n, b)
    # No flips: consecutive normals turn by a few degrees at most.
    assert np.einsum("ij,ij->i", n[1:], n[:-1]).min() > 0.95


@pytest.mark.parametrize("name", list(curves()))
def test_frenet_is_orthonormal(name: str) -> None:
    t, n, b = frenet_frames(curves()[name])
    assert_orthonormal(t, n, b)


def test_frenet_flips_where_rmf_does_not() -> None:
    # The S-curve's curvature changes sign: Frenet normals turn over, RMF normals do not.
    s_curve = curves()["s-curve"]
    _, n_frenet, _ = frenet_frames(s_curve)
    _, n_rmf, _ = rotation_minimizing_frames(s_curve)
    assert np.einsum("ij,ij->i", n_frenet[1:], n_frenet[:-1]).min() < -0.9
    assert np.einsum("ij,ij->i", n_rmf[1:], n_rmf[:-1]).min() > 0.99


def test_rmf_on_a_straight_line_is_constant() -> None:
    _, n, b = rotation_minimizing_frames(curves()["straight"])
    np.testing.assert_allclose(n, np.broadcast_to(n[0], n.shape), atol=1e-12)
    np.testing.assert_allclose(b, np.broadcast_to(b[0], b.shape), atol=1e-12)


def test_rmf_matches_sequential_double_reflection() -> None:
    pts = curves()["noisy"]
    t, n, _ = rotation_minimizing_frames(pts)
    r = [n[0]]
    for i in range(len(pts) - 1):
        v1 = pts[i + 1] - pts[i]
        c1 = v1 @ v1
        r_l = r[-1] - 2 / c1 * (v1 @ r[-1]) * v1
        t_l = t[i] - 2 / c1 * (v1 @ t[i]) * v1
        v2 = t[i + 1] - t_l
        c2 = v2 @ v2
        r.append(r_l - 2 / c2 * (v2 @ r_l) * v2 if c2 > 0 else r_l)
    np.testing.assert_allclose(np.array(r), n, atol=1e-10)


def test_repeated_points_do_not_zero_frames() -> None:
    pts = curves()["helix"].copy()
    pts[100:110] = pts[100]  # the robot paused
    t, n, b = rotation_minimizing_frames(pts)
    assert_orthonormal(t, n, b)


def test_planar_frames() -> None:
    s = np.linspace(0, np.pi, 50)
    t, n = planar_frames(np.column_stack([np.cos(s), np.sin(s)]))
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1)
    assert np.abs(np.einsum("ij,ij->i", t, n)).max() < 1e-12
    np.testing.assert_allclose(t[:, 0] * n[:, 1] - t[:, 1] * n[:, 0], 1.0)  # n is t turned left


def loop_smoothed_curve(points: np.ndarray, sigma: float) -> np.ndarray:
    """The smoothing as its docstring states it: one weighted shifted copy at a time."""
    n = points.shape[0]
    if sigma <= 0.0 or n < 3:
        return points
    k = min(max(1, int(np.ceil(4.0 * sigma))), n - 1)
    padded = np.concatenate([2.0 * points[0] - points[k:0:-1], points, 2.0 * points[-1] - points[-2 : -k - 2 : -1]])
    offsets = np.arange(-k, k + 1)
    weights = np.exp(-0.5 * (offsets / sigma) ** 2)
    weights /= weights.sum()
    out = np.zeros_like(points)
    for w, o in zip(weights, offsets, strict=True):
        out += w * padded[k + o : k + o + n]
    return out


@pytest.mark.parametrize("chunk", [1 << 20, 7, 1])
def test_smoothed_curve_adds_the_copies_in_order(chunk: int, monkeypatch: pytest.MonkeyPatch) -> None:
    # Bit for bit: the smoothed directrix decides the planes, and a plane moved by one
    # rounding step can change which segment a crossing test takes. Small chunks check
    # that each chunk continues the running sum in order (sum of a chunk, then added,
    # would round differently).
    monkeypatch.setattr(frames, "SMOOTHING_CHUNK", chunk)
    rng = np.random.default_rng(3)
    for _ in range(12):
        n, dim = int(rng.integers(3, 400)), int(rng.integers(2, 4))
        points = rng.normal(size=(n, dim)).cumsum(axis=0) * 10.0 ** rng.uniform(-3.0, 3.0)
        sigma = float(rng.uniform(0.2, 30.0))
        np.testing.assert_array_equal(smoothed_curve(points, sigma), loop_smoothed_curve(points, sigma))
