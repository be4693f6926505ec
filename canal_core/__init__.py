"""canal_core: learning from demonstration with canal surfaces, as pure numpy/scipy functions.

Ahmadzadeh & Chernova, "Encoding Demonstrations and Learning New Trajectories using Canal
Surfaces". Quick use::

    import canal_core
    canal = canal_core.fit(demos, cross_section="ellipse")
    canal.reproduce(start)        # (N', D) trajectory by the ratio rule
    canal_core.fit(demos, orientations=quats).reproduce_detailed(start, start_orientation=q)
    canal.contains(points)        # (M,) bool
    canal.mesh()                  # Mesh(vertices, faces, normals)
    canal_core.Canal.from_dict(canal.to_dict())
"""

from . import datasets, metrics, obstacles, routes
from .cross_sections import CrossSections
from .errors import (
    CanalError,
    DegenerateCanalError,
    InvalidInputError,
    ModelFormatError,
    OutsideCanalError,
    TooSlowError,
)
from .fit import fit
from .model import Canal
from .options import FitOptions, fit_options
from .orientation import OrientationModel
from .reproduction import Reproduction
from .routes import RouteChoice, Routes, fit_routes
from .sections import SectionKind, register_section_kind, section_kind, section_kinds
from .surface import Mesh
from .tracker import Tracker, TrackerTarget

__version__ = "0.2.0"

__all__ = [
    "Canal",
    "CanalError",
    "CrossSections",
    "DegenerateCanalError",
    "FitOptions",
    "InvalidInputError",
    "Mesh",
    "ModelFormatError",
    "OrientationModel",
    "OutsideCanalError",
    "Reproduction",
    "RouteChoice",
    "Routes",
    "SectionKind",
    "TooSlowError",
    "Tracker",
    "TrackerTarget",
    "__version__",
    "datasets",
    "fit",
    "fit_options",
    "fit_routes",
    "metrics",
    "obstacles",
    "register_section_kind",
    "routes",
    "section_kind",
    "section_kinds",
]
