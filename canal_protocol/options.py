"""The fit options of the HTTP contract, derived from :mod:`canal_core` (never written out).

The names a client may choose are canal_core's: the ``Literal`` aliases of
:mod:`canal_core.options` for frames, alignment and directrix, and canal_core's cross-section
names for ``cross_section`` (``canal_core.options.CROSS_SECTIONS``, the tuple ``fit``
validates against). Defaults are :class:`canal_core.options.FitOptions`'s, limits are
canal_core's constants. A new cross-section kind in canal_core is therefore accepted by the
service, offered by the client and listed in the OpenAPI schema without touching this package.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Literal

from canal_core import options as _core

__all__ = [
    "ALIGNMENTS",
    "CORRECTION_KINDS",
    "CROSS_SECTIONS",
    "DEFAULTS",
    "DIRECTRICES",
    "FRAMES",
    "MAX_CORRECTION_SAMPLES",
    "MAX_FRAME_SMOOTHING",
    "MAX_ROUTES",
    "MAX_ROUTE_SEPARATION",
    "MAX_SAMPLES",
    "MIN_CORRECTION_SAMPLES",
    "MIN_ROUTE_SEPARATION",
    "MIN_SAMPLES",
    "OUTSIDE_RULES",
    "PERSISTENCES",
    "RECORDING_MAGIC",
    "ROUTE_SEPARATION",
    "TIME_UNITS",
    "Alignment",
    "CorrectionKind",
    "CrossSection",
    "Directrix",
    "FrameKind",
    "OutsideRule",
    "Persistence",
    "RecordingKind",
    "TimeUnit",
]


#: The names ``canal_core.fit`` accepts (its validator checks against the same tuple).
CROSS_SECTIONS: tuple[str, ...] = tuple(_core.CROSS_SECTIONS)
FRAMES = _core.FRAMES
ALIGNMENTS = _core.ALIGNMENTS
DIRECTRICES = _core.DIRECTRICES
OUTSIDE_RULES = _core.OUTSIDE_RULES
PERSISTENCES = _core.PERSISTENCES
MIN_SAMPLES = _core.MIN_SAMPLES
#: The service accepts every N the core fits: one limit (docs/CONTRACTS.md says why 5,000).
MAX_SAMPLES = _core.MAX_SAMPLES
MAX_FRAME_SMOOTHING = _core.MAX_FRAME_SMOOTHING
#: Routes: how many may be forced, and the clustering's cut (canal_core.options.route_options).
MAX_ROUTES = _core.MAX_ROUTES
ROUTE_SEPARATION = _core.DEFAULT_ROUTE_SEPARATION
MIN_ROUTE_SEPARATION = _core.MIN_ROUTE_SEPARATION
MAX_ROUTE_SEPARATION = _core.MAX_ROUTE_SEPARATION
#: canal_core's defaults: what a request that leaves an option out gets.
DEFAULTS = _core.FitOptions()

FrameKind = _core.FrameKind
Alignment = _core.AlignmentKind
Directrix = _core.DirectrixKind
OutsideRule = _core.OutsideRule
Persistence = _core.Persistence
#: Corrections: the kinds a person may send and the sizes canal_core accepts.
CorrectionKind = _core.CorrectionKind
CORRECTION_KINDS = _core.CORRECTION_KINDS
MIN_CORRECTION_SAMPLES = _core.MIN_CORRECTION_SAMPLES
MAX_CORRECTION_SAMPLES = _core.MAX_CORRECTION_SAMPLES
#: Largest weight of an include correction (in demonstrations), over REST and live.
MAX_CORRECTION_WEIGHT = 1000.0
#: Longest label of a demonstration and of a correction, over REST and live.
MAX_DEMO_LABEL = 256
MAX_CORRECTION_LABEL = 200
#: The units a demonstration's or a correction's ``time_unit`` names.
TimeUnit = Literal["s", "ms", "us", "ns"]
#: Seconds per unit of a demonstration's ``time_unit`` (a CSV/NPY time column, JSON timestamps).
TIME_UNITS: dict[str, float] = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
#: The recordings a skill has: Rerun (.rrd) and MCAP.
RecordingKind = Literal["rrd", "mcap"]
#: How each recording file starts: Rerun's ``RRF`` and its encoding's version digit, and the
#: MCAP magic (what an .mcap upload starts with too).
RECORDING_MAGIC: dict[str, bytes] = {"rrd": b"RRF", "mcap": b"\x89MCAP0\r\n"}
if TYPE_CHECKING:
    # The registry is open (a new kind is one new module), so statically it is a name.
    CrossSection = str
else:
    CrossSection = Literal[CROSS_SECTIONS]
