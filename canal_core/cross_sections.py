"""Cross-sections of the canal (paper Section 4.1, "Estimating the Radii"; Fig. 1 and 3): the façade.

Every operation looks the kind up in the registry (:mod:`canal_core.sections`) and calls
that kind's function; nothing here knows a kind's parameters. See
:mod:`canal_core.sections` for the kinds and :mod:`canal_core.sections.base` for the
contract each keeps (containment by construction, star-shaped about c_i).
"""

from __future__ import annotations

from .sections import (
    CrossSections,
    SectionKind,
    register_section_kind,
    sampled_radii,
    section_kind,
    section_kinds,
)
from .sections.base import RELATIVE_FLOOR, TWO_PI
from .sections.circle import circle_sections
from .sections.ellipse import (
    ELLIPSE_RELATIVE_FLOOR,
    KHACHIYAN_MAX_ITERATIONS,
    KHACHIYAN_TOLERANCE,
    ellipse_matrices,
    ellipse_sections,
    khachiyan_ellipses,
)
from .sections.interval import interval_sections
from .sections.mec import MEC_ENUMERATION_LIMIT, mec_sections
from .sections.spline import (
    SPLINE_FLOOR,
    SPLINE_GUIDES,
    hull_radial_function,
    periodic_spline_second_derivatives,
    periodic_spline_values,
    spline_sections,
)
from .validation import FloatArray, IntArray

#: The built-in kinds (registered ones: :func:`section_kinds`).
KINDS_3D = ("circle", "mec", "ellipse", "spline")
KINDS = (*KINDS_3D, "interval")


def boundary_distance(sections: CrossSections, index: IntArray, direction: FloatArray) -> FloatArray:
    """Distance from c_i to the boundary of section i along an in-plane unit direction.

    This is |g_i c_i| of the ratio rule (Alg. 1 line 10, Fig. 4).

    Parameters
    ----------
    sections : CrossSections
    index : array of int, shape (M,)
        Section of each query.
    direction : array, shape (M, D - 1)
        Unit in-plane directions (2-D: +-1 on the normal line).

    Returns
    -------
    distance : array, shape (M,)
        Non-negative.
    """
    return sections.spec.boundary_distance(sections, index, direction)


def fitted_sections(coords: FloatArray, kind: str) -> CrossSections:
    """Fit cross-sections of ``kind`` to in-plane crossings.

    Parameters
    ----------
    coords : array, shape (N, n, D - 1)
    kind : str
        A registered 3-D kind (``circle``, ``mec``, ``ellipse``, ``spline`` built in); in
        2-D every kind becomes an ``interval``, symmetric for an isotropic kind (``circle``).
    """
    spec = section_kind(kind)
    if coords.shape[2] == 1:
        return interval_sections(coords, symmetric=spec.isotropic)
    return spec.fitted(coords)


def section_radii(sections: CrossSections, n_angles: int = 64) -> FloatArray:
    """Largest boundary distance from c_i per section, shape (N,) (for plots and colour ramps)."""
    radii = sections.spec.radii
    return radii(sections) if radii is not None else sampled_radii(sections, n_angles)


def scaled_sections(sections: CrossSections, scale: FloatArray) -> CrossSections:
    """Sections enlarged by a homothety about c_i: every boundary distance times ``scale`` (N,)."""
    return sections.spec.scaled(sections, scale)


def floored_sections(sections: CrossSections, floor: float) -> CrossSections:
    """Sections whose boundary lies at least about ``floor`` from c_i in every direction.

    The fit (:func:`canal_core.enclosing.enclosing_scales`) grows sections by a
    homothety about c_i, which cannot enlarge a boundary that passes through c_i (a zero
    radius, a one-sided interval, a spline knot of radius 0). ``floor`` is a tiny length
    (1e-9 of the canal's size in :func:`canal_core.fit`), so every other section is unchanged.

    Parameters
    ----------
    sections : CrossSections
    floor : float
        Smallest boundary distance, in the data's units.
    """
    return sections.spec.floored(sections, floor)


__all__ = [
    "ELLIPSE_RELATIVE_FLOOR",
    "KHACHIYAN_MAX_ITERATIONS",
    "KHACHIYAN_TOLERANCE",
    "KINDS",
    "KINDS_3D",
    "MEC_ENUMERATION_LIMIT",
    "RELATIVE_FLOOR",
    "SPLINE_FLOOR",
    "SPLINE_GUIDES",
    "TWO_PI",
    "CrossSections",
    "SectionKind",
    "boundary_distance",
    "circle_sections",
    "ellipse_matrices",
    "ellipse_sections",
    "fitted_sections",
    "floored_sections",
    "hull_radial_function",
    "interval_sections",
    "khachiyan_ellipses",
    "mec_sections",
    "periodic_spline_second_derivatives",
    "periodic_spline_values",
    "register_section_kind",
    "scaled_sections",
    "section_kind",
    "section_kinds",
    "section_radii",
    "spline_sections",
]
