"""Shared autonomy: a person's 2-D input moves the plan across the section while the canal
carries it along (after GeoSACS, Rajapakshe et al. 2024).

A joystick gives (u, v) in [-1, 1]. They are read in two in-plane axes that do not twist
along the path: v along world "up" (+z) projected onto the section plane, u = v x t
(left of the direction of travel); where the path runs nearly vertical, u is world +y
projected instead and v = t x u. The rotation-minimising frame (n, b) turns with the path's
torsion, so "left" in it would not stay left; these axes do.

The plan is the tracker's ratio vector p = eta (cos, sin) in (n, b) coordinates (its
``eta`` and ``direction``). Steering moves it at a rate of ``rate`` ratio units per second
at full deflection and clips it to ``max_eta`` < 1::

    p' = clip(p + rate dt (u a_u + v a_v)),   |p'| <= max_eta            (S1)

with a_u, a_v the axes in (n, b) coordinates. The target built from p' is the ratio rule's,
so it never leaves the canal; the tracker keeps a plan while the robot follows it, so a
steered plan stays steered, and with no input for ``STEER_TIMEOUT_S`` the tracker carries
the last ratio on, by the plain ratio rule.

In 2-D there is one in-plane axis, the left normal; u moves along it and v is ignored.
"""

from __future__ import annotations

import math

import numpy as np

from .tracker import MAX_PLAN_ETA
from .validation import FloatArray

#: Ratio units per second at full deflection: across half the canal in about 2 s.
STEER_RATE = 0.5
#: No input for this long returns the stream to the plain ratio rule.
STEER_TIMEOUT_S = 0.5
#: Where the projected world axis is shorter than this, the other world axis is used.
_VERTICAL = 0.3


def steering_axes(tangents: FloatArray, basis: FloatArray) -> FloatArray:
    """The u and v axes of every section in in-plane coordinates, shape (N, 2, D - 1).

    Parameters
    ----------
    tangents : array, shape (N, D)
    basis : array, shape (N, D - 1, D)
    """
    n, k = basis.shape[0], basis.shape[1]
    if k == 1:
        axes = np.zeros((n, 2, 1))
        axes[:, 0, 0] = 1.0
        return axes
    up = np.array([0.0, 0.0, 1.0])
    v = up[None, :] - (tangents @ up)[:, None] * tangents
    norm = np.linalg.norm(v, axis=1)
    u = np.cross(v, tangents)
    vertical = norm < _VERTICAL
    if vertical.any():
        side = np.array([0.0, 1.0, 0.0])
        t = tangents[vertical]
        u_alt = side[None, :] - (t @ side)[:, None] * t
        u[vertical] = u_alt
        v[vertical] = np.cross(t, u_alt)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    return np.stack([np.einsum("nkd,nd->nk", basis, u), np.einsum("nkd,nd->nk", basis, v)], axis=1)


def steered_plan(eta: float, direction: FloatArray, axes: FloatArray, u: float, v: float,
                 dt: float, rate: float = STEER_RATE, max_eta: float = MAX_PLAN_ETA
                 ) -> tuple[float, FloatArray]:
    """The plan (eta, unit direction (D - 1,)) moved by a steering input (S1).

    Parameters
    ----------
    eta : float
    direction : array, shape (D - 1,)
    axes : array, shape (2, D - 1)
        The section's u and v axes (:func:`steering_axes`).
    u, v : float
        In [-1, 1].
    dt : float
        Seconds since the plan was last steered.
    """
    p = eta * direction + (rate * dt) * (u * axes[0] + v * axes[1])
    norm = math.sqrt(float(p @ p))
    if norm > max_eta:
        p *= max_eta / norm
        norm = max_eta
    if norm == 0.0:
        return 0.0, direction
    return norm, p / norm


__all__ = ["STEER_RATE", "STEER_TIMEOUT_S", "steered_plan", "steering_axes"]
