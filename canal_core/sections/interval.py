"""``interval``: the sections of a 2-D canal, [lower, upper] on the normal line, lower <= 0 <= upper.

Every 3-D kind becomes an interval in 2-D: symmetric ``[-r, r]`` for an isotropic kind (the
1-D circle), tight and asymmetric for every other kind.
"""

from __future__ import annotations

import numpy as np

from ..validation import FloatArray, IntArray
from .base import CrossSections, SectionKind, copied_params


def interval_sections(coords: FloatArray, symmetric: bool = False) -> CrossSections:
    """2-D sections: the interval on the normal line holding c_i and every crossing.

    Parameters
    ----------
    coords : array, shape (N, n, 1)
    symmetric : bool
        ``[-r, r]`` with r the largest offset (the 1-D circle) when True.
    """
    offsets = coords[:, :, 0]
    if symmetric:
        radius = np.abs(offsets).max(axis=1)
        return CrossSections("interval", {"lower": -radius, "upper": radius})
    return CrossSections(
        "interval",
        {"lower": np.minimum(offsets.min(axis=1), 0.0), "upper": np.maximum(offsets.max(axis=1), 0.0)},
    )


def interval_distance(sections: CrossSections, index: IntArray, direction: FloatArray) -> FloatArray:
    """``upper`` along +n, ``-lower`` along -n, shape (M,)."""
    p = sections.params
    return np.where(direction[:, 0] >= 0.0, p["upper"][index], -p["lower"][index])


def scaled_intervals(sections: CrossSections, scale: FloatArray) -> CrossSections:
    p = sections.params
    return CrossSections("interval", {"lower": p["lower"] * scale, "upper": p["upper"] * scale})


def floored_intervals(sections: CrossSections, floor: float) -> CrossSections:
    p = copied_params(sections)
    p["lower"] = np.minimum(p["lower"], -floor)
    p["upper"] = np.maximum(p["upper"], floor)
    return CrossSections("interval", p)


def interval_radii(sections: CrossSections) -> FloatArray:
    return np.maximum(sections.params["upper"], -sections.params["lower"])


INTERVAL = SectionKind(
    name="interval",
    params=("lower", "upper"),
    fitted=interval_sections,
    boundary_distance=interval_distance,
    scaled=scaled_intervals,
    floored=floored_intervals,
    in_plane_dim=1,
    radii=interval_radii,
)
