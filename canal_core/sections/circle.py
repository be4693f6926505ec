"""``circle``: centred on c_i, radius = the largest distance to a demo crossing.

The paper's choice (Section 4.1: "the vertex with a maximum distance from the center"); the
only isotropic built-in kind, so the true envelope of Eq. 9 and the tracker's fast path apply.
"""

from __future__ import annotations

import numpy as np

from ..validation import FloatArray, IntArray
from .base import CrossSections, SectionKind, copied_params


def circle_sections(coords: FloatArray) -> CrossSections:
    """Circles centred on the directrix through the farthest crossing.

    Parameters
    ----------
    coords : array, shape (N, n, 2)
    """
    # Elementwise over the demos (a reduction over the short demo axis costs more).
    square = coords[:, :, 0] * coords[:, :, 0]
    for axis in range(1, coords.shape[2]):
        square += coords[:, :, axis] * coords[:, :, axis]
    return CrossSections("circle", {"radius": np.sqrt(np.maximum.reduce(square.T, axis=0))})


def circle_distance(sections: CrossSections, index: IntArray, direction: FloatArray) -> FloatArray:
    """The radius, whatever the direction, shape (M,)."""
    return sections.params["radius"][index]


def scaled_circles(sections: CrossSections, scale: FloatArray) -> CrossSections:
    """Radii times ``scale`` (N,)."""
    return CrossSections("circle", {"radius": sections.params["radius"] * scale})


def floored_circles(sections: CrossSections, floor: float) -> CrossSections:
    """Radii of at least ``floor``."""
    p = copied_params(sections)
    p["radius"] = np.maximum(p["radius"], floor)
    return CrossSections("circle", p)


def circle_radii(sections: CrossSections) -> FloatArray:
    return sections.params["radius"].copy()


CIRCLE = SectionKind(
    name="circle",
    params=("radius",),
    fitted=circle_sections,
    boundary_distance=circle_distance,
    scaled=scaled_circles,
    floored=floored_circles,
    isotropic=True,
    radii=circle_radii,
)
