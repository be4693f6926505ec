"""Steering: fixed-world axes that do not twist, and a plan that never leaves the canal."""

from __future__ import annotations

import numpy as np
from core_data import helix_demos

import canal_core
from canal_core.steering import steered_plan, steering_axes
from canal_core.tracker import MAX_PLAN_ETA


def test_left_stays_left_along_a_twisting_helix() -> None:
    canal = canal_core.fit(helix_demos(0.05, 6), n_samples=200)
    axes = steering_axes(canal.tangents, canal.basis)
    # The u axis in world coordinates is horizontal and to the left of travel everywhere.
    u_world = np.einsum("nk,nkd->nd", axes[:, 0], canal.basis)
    v_world = np.einsum("nk,nkd->nd", axes[:, 1], canal.basis)
    np.testing.assert_allclose(np.linalg.norm(u_world, axis=1), 1.0, atol=1e-9)
    assert np.abs(u_world[:, 2]).max() < 1e-9
    assert (v_world[:, 2] > 0.5).all()
    left = np.cross([0.0, 0.0, 1.0], canal.tangents)
    assert (np.einsum("nd,nd->n", u_world, left) > 0.9).all()
    # The frame (n, b) itself turns with the helix: in it, the axes are not constant.
    assert np.ptp(np.arctan2(axes[:, 0, 1], axes[:, 0, 0])) > 0.5


def test_full_deflection_reaches_the_wall_and_stops_inside() -> None:
    axes = np.array([[1.0, 0.0], [0.0, 1.0]])
    eta, direction = 0.0, np.array([1.0, 0.0])
    for _ in range(5000):
        eta, direction = steered_plan(eta, direction, axes, 1.0, 1.0, 0.001)
    assert abs(eta - MAX_PLAN_ETA) < 1e-12
    np.testing.assert_allclose(direction, np.array([1.0, 1.0]) / np.sqrt(2.0), atol=1e-9)
    eta, direction = steered_plan(eta, direction, axes, 0.0, 0.0, 0.5)
    assert abs(eta - MAX_PLAN_ETA) < 1e-12  # no input: the plan stays where it was


def test_a_planar_canal_steers_along_its_normal() -> None:
    x = np.linspace(0.0, 1.0, 50)
    canal = canal_core.fit([np.column_stack([x, 0.1 * x + dy]) for dy in (-0.05, 0.05)], n_samples=40)
    axes = steering_axes(canal.tangents, canal.basis)
    assert axes.shape == (40, 2, 1) and (axes[:, 0, 0] == 1.0).all()
    eta, direction = steered_plan(0.2, np.array([1.0]), axes[0], -1.0, 0.0, 1.0)
    assert abs(eta - 0.3) < 1e-12 and direction[0] == -1.0
