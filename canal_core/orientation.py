"""Orientation along the canal: per-section mean and spread, and the ratio rule for rotations.

The paper learns and reproduces positions only. A pose skill (pouring, inserting) also needs
the tool's orientation, so when every demonstration carries unit quaternions
``[qx, qy, qz, qw]`` this module learns them on the positions' alignment and reproduces them
with a rotational counterpart of the ratio rule (docs/orientation.md has the equations beside
the paper's):

* **mean** (the orientation directrix, counterpart of Alg. 1 line 4): per section k, Markley's
  average of the n aligned demo quaternions, the unit eigenvector of the largest eigenvalue of
  ``M_k = sum_j q_jk q_jk^T``. ``q q^T`` is the same for q and -q, so the sign each demo's
  driver chose does not matter.
* **spread** (the counterpart of the radius, Alg. 1 line 5): the largest geodesic angle of a
  demo from the section mean, ``sigma_k = max_j 2 acos |<q_jk, m_k>|``.
* **offsets**: each demo's offset from the mean in the mean's own (tool) frame, as a rotation
  vector ``v_jk = log(m_k^-1 q_jk)`` (the counterpart of ``section_points``); ``|v_jk|`` is
  the angle the spread is the maximum of.
* **reproduction** (counterpart of the ratio rule, Alg. 1 line 13): the start's offset
  ``v_0 = log(m_i0^-1 q_0)`` is carried to section k scaled by how much the demonstrations'
  own offsets persisted from section i0 to k, the least-squares gain
  ``g_k = clip(sum_j <v_jk, v_ji0> / sum_j |v_ji0|^2, 0, 1)`` (lightly smoothed along the
  canal), so ``q_k = m_k exp(g_k v_0)``. ``g_i0 = 1``: the path starts at the start
  orientation. Where the demos kept their offsets (a grasp held rotated) the start's offset
  is kept; where their offsets were unrelated to where they started (the real UR5e reaches),
  it blends back to the mean. The paper's position ratio rule assumes persistence (eta is
  constant); for orientation we measured it does not hold on real data (docs/orientation.md).

All arrays are float64; quaternions are scalar-last, as ROS and scipy write them.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from .errors import ModelFormatError
from .validation import FloatArray

#: Spreads below this angle (radians) count as zero: the demonstrations agree exactly.
MIN_SPREAD = 1e-9
#: Gaussian smoothing of the carry gain along the canal, as a fraction of the sections: the
#: gain is a regression on a handful of demos and would otherwise jitter section to section.
GAIN_SMOOTHING = 0.01


def hemisphere_continuous(quaternions: FloatArray, reference: FloatArray | None = None) -> FloatArray:
    """Flip signs so consecutive quaternions are on the same hemisphere, shape (T, 4).

    q and -q are one rotation; a path that jumps between them is correct but useless to a
    controller that interpolates component-wise. The first row is put on the hemisphere of
    ``reference`` (4,) when given, else on the one with qw >= 0.

    Parameters
    ----------
    quaternions : array, shape (T, 4)
    reference : array, shape (4,), optional
    """
    q = np.array(quaternions, dtype=np.float64, copy=True)
    if q.shape[0] == 0:
        return q
    dots = np.einsum("td,td->t", q[1:], q[:-1])
    # A flip at step t flips every later row: the cumulative parity of the negative steps.
    flips = np.concatenate([[False], np.logical_xor.accumulate(dots < 0.0)])
    q[flips] *= -1.0
    first = q[0, 3] if reference is None else float(q[0] @ reference)
    if first < 0.0:
        q *= -1.0
    return q


def slerped(a: FloatArray, b: FloatArray, shares: FloatArray) -> FloatArray:
    """Unit quaternions from ``a`` (4,) to ``b`` (4,) at ``shares`` (K,) of the shortest
    rotation between them, shape (K, 4), on the hemisphere of ``a``."""
    from scipy.spatial.transform import Rotation, Slerp

    turn = Slerp([0.0, 1.0], Rotation.from_quat(np.vstack([a, b])))(np.asarray(shares, dtype=np.float64))
    return hemisphere_continuous(turn.as_quat(), a)


def aligned_orientations(
    quaternions: list[FloatArray], parameters: list[FloatArray], at: FloatArray
) -> FloatArray:
    """Each demo's orientation at the alignment's parameter values, by slerp.

    Parameters
    ----------
    quaternions : list of arrays, each shape (T_j, 4)
        Unit quaternions of the cleaned demonstrations.
    parameters : list of arrays, each shape (T_j,)
        Strictly increasing curve parameter of each sample, from 0 to 1 (the one the
        positions were aligned by, :func:`canal_core.alignment.spline_parameter`).
    at : array, shape (n, N)
        Parameter of every aligned sample of every demo.

    Returns
    -------
    aligned : array, shape (n, N, 4)
    """
    from scipy.spatial.transform import Rotation, Slerp

    out = np.empty((len(quaternions), at.shape[1], 4))
    for j, (q, u) in enumerate(zip(quaternions, parameters, strict=True)):
        slerp = Slerp(u, Rotation.from_quat(q))
        out[j] = slerp(np.clip(at[j], u[0], u[-1])).as_quat()
    return out


def mean_orientations(aligned: FloatArray) -> FloatArray:
    """Markley's average of the demos' orientations per section, shape (N, 4).

    Parameters
    ----------
    aligned : array, shape (n, N, 4)

    Returns
    -------
    means : array, shape (N, 4)
        Unit quaternions, hemisphere-continuous along the canal (first with qw >= 0).

    Notes
    -----
    The largest-eigenvalue eigenvector of ``sum_j q_j q_j^T`` (Markley et al. 2007,
    "Averaging quaternions"), the same mean as scipy's ``Rotation.mean``, computed for all
    sections in one batched ``eigh``.
    """
    scatter = np.einsum("jni,jnk->nik", aligned, aligned)
    _, vectors = np.linalg.eigh(scatter)
    means = vectors[:, :, -1]
    means /= np.linalg.norm(means, axis=1, keepdims=True)
    return hemisphere_continuous(means)


def angles_between(a: FloatArray, b: FloatArray) -> FloatArray:
    """Geodesic angle in radians between rotations ``a`` and ``b`` (..., 4), sign-blind.

    ``2 atan2(|a^-1 b|_vec, |<a, b>|)``: stable near 0 and near pi, unlike ``2 acos``.
    """
    dot = np.abs(np.einsum("...d,...d->...", a, b))
    norm = np.sqrt(np.einsum("...d,...d->...", a, a) * np.einsum("...d,...d->...", b, b))
    # |a^-1 b| vector part = sqrt(|a|^2 |b|^2 - <a, b>^2) for any quaternions a, b.
    vec = np.sqrt(np.maximum(norm * norm - dot * dot, 0.0))
    return np.asarray(2.0 * np.arctan2(vec, dot))


def orientation_offsets(aligned: FloatArray, means: FloatArray) -> FloatArray:
    """Each demo's offset from its section mean as a rotation vector in the mean's frame.

    Parameters
    ----------
    aligned : array, shape (n, N, 4)
    means : array, shape (N, 4)

    Returns
    -------
    offsets : array, shape (N, n, 3)
        ``log(m_k^-1 q_jk)``; its norm is the geodesic angle, in [0, pi].
    """
    from scipy.spatial.transform import Rotation

    n, count = aligned.shape[:2]
    rel = Rotation.from_quat(np.tile(means, (n, 1))).inv() * Rotation.from_quat(aligned.reshape(-1, 4))
    return np.asarray(rel.as_rotvec().reshape(n, count, 3).transpose(1, 0, 2))


def start_offset(mean: FloatArray, start: FloatArray) -> FloatArray:
    """The start orientation's offset from its section mean, ``log(m^-1 q_0)``, shape (3,)."""
    from scipy.spatial.transform import Rotation

    return np.asarray((Rotation.from_quat(mean).inv() * Rotation.from_quat(start)).as_rotvec())


def carry_gains(offsets: FloatArray, section: int, smoothing: float = GAIN_SMOOTHING) -> FloatArray:
    """How much of an offset at ``section`` the demos kept at every section, in [0, 1], shape (N,).

    ``g_k = sum_j <v_jk, v_js> / sum_j |v_js|^2``, the least-squares gain of the demos' offsets
    at k on their offsets at s, smoothed by a Gaussian of ``smoothing * N`` sections, then
    clipped to [0, 1]. All zeros when the demos agree exactly at ``section``.

    Parameters
    ----------
    offsets : array, shape (N, n, 3)
    section : int
    smoothing : float
    """
    from scipy.ndimage import gaussian_filter1d

    ref = offsets[section]
    energy = float(np.einsum("jd,jd->", ref, ref))
    if energy <= MIN_SPREAD**2:
        return np.zeros(offsets.shape[0])
    gains = np.einsum("kjd,jd->k", offsets, ref) / energy
    sigma = smoothing * offsets.shape[0]
    if sigma > 0.0:
        gains = gaussian_filter1d(gains, sigma, mode="nearest")
    return np.clip(gains, 0.0, 1.0)


def carried_orientations(means: FloatArray, gains: FloatArray, offset: FloatArray) -> FloatArray:
    """The carried offset: ``q_k = m_k exp(g_k v_0)`` per section, shape (K, 4).

    Parameters
    ----------
    means : array, shape (K, 4)
        Section means the path passes.
    gains : array, shape (K,)
        Their carry gains (:func:`carry_gains`).
    offset : array, shape (3,)
        The start's offset v_0 (:func:`start_offset`).
    """
    from scipy.spatial.transform import Rotation

    return np.asarray((Rotation.from_quat(means) * Rotation.from_rotvec(gains[:, None] * offset[None, :])).as_quat())


@dataclass(frozen=True, eq=False)
class OrientationModel:
    """What a canal learned about orientation.

    Attributes
    ----------
    means : array, shape (N, 4)
        Per-section mean orientation, unit quaternions [qx, qy, qz, qw].
    offsets : array, shape (N, n, 3)
        Each demo's offset from the mean, rotation vectors in the mean's frame (radians).
    """

    means: FloatArray
    offsets: FloatArray

    @cached_property
    def spreads(self) -> FloatArray:
        """Per-section largest angle (radians) of a demonstration from the mean, shape (N,)."""
        return np.asarray(np.linalg.norm(self.offsets, axis=2).max(axis=1))

    def reproduced(
        self, section: int, first: int, start: FloatArray | None
    ) -> tuple[FloatArray, float | None]:
        """Orientations for a reproduction that starts at ``section``, shape (1 + N - first, 4).

        The first row is the start orientation (or the section mean without one), then one per
        section from ``first`` to the end, as the positions of the ratio rule. Also returns the
        start's angle from its section mean over the section's spread (None without a start
        orientation; inf when the demos agree exactly there and the start does not).
        """
        if start is None:
            rows = np.vstack([self.means[section], self.means[first:]])
            return hemisphere_continuous(rows), None
        offset = start_offset(self.means[section], start)
        angle, spread = float(np.linalg.norm(offset)), float(self.spreads[section])
        ratio = angle / spread if spread > MIN_SPREAD else (0.0 if angle == 0.0 else float("inf"))
        gains = carry_gains(self.offsets, section)[first:]
        path = carried_orientations(self.means[first:], gains, offset)
        return hemisphere_continuous(np.vstack([start, path]), start), ratio

    def to_dict(self) -> dict[str, Any]:
        return {"means": self.means.tolist(), "offsets": self.offsets.tolist()}

    @classmethod
    def from_dict(cls, data: Any, n_sections: int) -> OrientationModel:
        """Rebuild from :meth:`to_dict`; raises :class:`ModelFormatError` on bad shapes."""
        if not isinstance(data, dict):
            raise ModelFormatError(f"expected orientation as a dict, got {type(data).__name__}",
                                   field="orientation")
        means = np.asarray(data["means"], dtype=np.float64)
        offsets = np.asarray(data["offsets"], dtype=np.float64)
        if means.shape != (n_sections, 4) or offsets.ndim != 3 or offsets.shape[0] != n_sections \
                or offsets.shape[2] != 3:
            raise ModelFormatError(
                f"expected orientation means ({n_sections}, 4) and offsets ({n_sections}, n, 3), "
                f"got {means.shape} and {offsets.shape}",
                field="orientation",
            )
        finite = np.isfinite(means).all() and np.isfinite(offsets).all()
        if not finite or np.abs(np.linalg.norm(means, axis=1) - 1.0).max(initial=0.0) > 1e-6:
            raise ModelFormatError("expected finite unit orientation means and finite offsets",
                                   field="orientation")
        return cls(means, offsets)


def fitted_orientations(
    quaternions: list[FloatArray], parameters: list[FloatArray], at: FloatArray
) -> OrientationModel:
    """Learn means and offsets from the demos' orientations on the positions' alignment.

    Parameters
    ----------
    quaternions, parameters, at
        See :func:`aligned_orientations`.
    """
    aligned = aligned_orientations(quaternions, parameters, at)
    means = mean_orientations(aligned)
    return OrientationModel(means, orientation_offsets(aligned, means))
