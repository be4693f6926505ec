"""What a cross-section kind is (:class:`SectionKind`) and the sections of one canal (:class:`CrossSections`).

A cross-section i lives in the plane through the directrix point c_i normal to t_i, in the
in-plane basis (n_i, b_i) (3-D) or (n_i,) (2-D) (paper Section 4.1, Fig. 1 and 3). A kind is
a frozen bundle of pure functions over its parameter arrays, looked up by name in
:mod:`canal_core.sections.registry`; nothing outside a kind's module knows its parameters.

The contract every kind keeps (what the fit, the ratio rule, the envelope and the mesh rely on):

* ``fitted`` returns sections that contain c_i and every crossing, exactly (measure the
  points against the fitted boundary and enlarge it if rounding left one out);
* every section is star-shaped about c_i, and ``boundary_distance`` gives |g_i c_i| of the
  ratio rule (Alg. 1 line 10, Fig. 4) along any in-plane unit direction;
* ``scaled`` is the homothety about c_i that multiplies every boundary distance of section i
  by ``scale[i]``; ``floored`` keeps the boundary at least about ``floor`` from c_i;
* ``isotropic`` kinds store their radius as ``params["radius"]`` (N,) and their boundary
  distance is that radius in every direction (the tracker's and Eq. 9's fast path).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..validation import FloatArray, IntArray
from .registry import section_kind

TWO_PI = 2.0 * np.pi
#: Relative size (of the canal's largest offset) below which a length counts as zero.
RELATIVE_FLOOR = 1e-9


@dataclass(frozen=True)
class SectionKind:
    """One kind of cross-section: its name and the pure functions every consumer calls.

    Attributes
    ----------
    name : str
        The key in the registry, in ``FitOptions.cross_section`` and in stored models.
    params : tuple of str
        Names of the parameter arrays; each has one row per section (N, ...).
    fitted : callable (coords (N, n, in_plane_dim)) -> CrossSections
        Sections holding c_i (the origin) and every crossing.
    boundary_distance : callable (sections, index (M,), direction (M, in_plane_dim)) -> (M,)
        Distance from c_i to the boundary along unit in-plane directions, non-negative.
    scaled : callable (sections, scale (N,)) -> CrossSections
        Homothety about c_i.
    floored : callable (sections, floor) -> CrossSections
        Boundary at least about ``floor`` from c_i in every direction.
    in_plane_dim : int
        2 for the sections of 3-D canals, 1 for those of 2-D canals.
    min_demos : int
        Fewest demonstrations a 3-D fit of this kind accepts.
    isotropic : bool
        Boundary distance independent of the direction, stored as ``params["radius"]``.
    derived : callable (params) -> dict of arrays, optional
        Arrays computed once from the params when sections are built (kept with them).
    radii : callable (sections) -> (N,), optional
        Largest boundary distance per section; sampled over 64 directions when absent.
    """

    name: str
    params: tuple[str, ...]
    fitted: Callable[[FloatArray], CrossSections]
    boundary_distance: Callable[[CrossSections, IntArray, FloatArray], FloatArray]
    scaled: Callable[[CrossSections, FloatArray], CrossSections]
    floored: Callable[[CrossSections, float], CrossSections]
    in_plane_dim: int = 2
    min_demos: int = 2
    isotropic: bool = False
    derived: Callable[[dict[str, FloatArray]], dict[str, FloatArray]] | None = None
    radii: Callable[[CrossSections], FloatArray] | None = None


@dataclass(frozen=True, eq=False)
class CrossSections:
    """The N cross-sections of a canal.

    Attributes
    ----------
    kind : str
        A registered kind (see :func:`canal_core.sections.section_kinds`); built in:
        ``circle``, ``mec``, ``ellipse``, ``spline``, ``interval``.
    params : dict of str to array
        Each kind's parameters, one row per section. ``circle``: radius (N,).
        ``mec``: center (N, 2), radius (N,). ``ellipse``: center (N, 2), axes (N, 2),
        angle (N,) (axes[:, 0] along angle). ``spline``: knot_angles (N, K),
        knot_radii (N, K), scale (N,). ``interval``: lower (N,), upper (N,).
    spec : SectionKind
        The registered kind (looked up on construction; unknown names raise
        :class:`~canal_core.errors.InvalidInputError`).
    """

    kind: str
    params: dict[str, FloatArray]
    # Arrays computed from params once (spline second derivatives need a linear solve per
    # section). Passed in only by kind modules, when the params they depend on are unchanged.
    _derived: dict[str, FloatArray] = field(default_factory=dict, repr=False)
    spec: SectionKind = field(init=False, repr=False)

    def __post_init__(self) -> None:
        spec = section_kind(self.kind)
        object.__setattr__(self, "spec", spec)
        if spec.derived is not None and not self._derived:
            self._derived.update(spec.derived(self.params))

    @property
    def n_sections(self) -> int:
        return int(next(iter(self.params.values())).shape[0])

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, **{k: v.tolist() for k, v in self.params.items()}}


def with_origin(coords: FloatArray) -> FloatArray:
    """Append c_i (the origin of each section) so every section contains its directrix point."""
    return np.concatenate([coords, np.zeros((coords.shape[0], 1, coords.shape[2]))], axis=1)


def sampled_radii(sections: CrossSections, n_angles: int = 64) -> FloatArray:
    """Largest boundary distance over ``n_angles`` in-plane directions per section, shape (N,)."""
    n = sections.n_sections
    angles = np.linspace(0.0, TWO_PI, n_angles, endpoint=False)
    dirs = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    index = np.repeat(np.arange(n), n_angles)
    dist = sections.spec.boundary_distance(sections, index, np.tile(dirs, (n, 1)))
    return np.asarray(dist.reshape(n, n_angles).max(axis=1), dtype=np.float64)


def copied_params(sections: CrossSections) -> dict[str, FloatArray]:
    """A copy of the parameter arrays (kinds build new sections, never mutate old ones)."""
    return {k: v.copy() for k, v in sections.params.items()}
