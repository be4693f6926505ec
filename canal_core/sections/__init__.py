"""Cross-section kinds behind one interface (paper Section 4.1, Fig. 1 and 3).

Each kind is one module defining a :class:`SectionKind` (pure functions over its parameter
arrays); :mod:`.registry` maps names to kinds. The built-in kinds are registered here:

``circle``   centred on c_i, radius = the largest distance to a demo crossing (the paper's).
``mec``      the minimum enclosing circle of the crossings and c_i.
``ellipse``  the minimum-area enclosing ellipse of the crossings and c_i.
``spline``   a closed periodic cubic spline r(theta) about c_i through the hull crossings.
``interval`` the sections of 2-D canals, [lower, upper] on the normal line.

A new kind: write a module with a ``SectionKind`` and call :func:`register_section_kind`.
"""

from __future__ import annotations

from .base import CrossSections, SectionKind, sampled_radii
from .circle import CIRCLE
from .ellipse import ELLIPSE
from .interval import INTERVAL
from .mec import MEC
from .registry import register_section_kind, section_kind, section_kinds, unregister_section_kind
from .spline import SPLINE

for _kind in (CIRCLE, MEC, ELLIPSE, SPLINE, INTERVAL):
    register_section_kind(_kind)

__all__ = [
    "CrossSections",
    "SectionKind",
    "register_section_kind",
    "sampled_radii",
    "section_kind",
    "section_kinds",
    "unregister_section_kind",
]
