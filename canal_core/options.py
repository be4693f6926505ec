"""The fit's options: the names a caller may choose, their defaults and their limits.

Each ``Literal`` is the one list of names; the tuples are derived from it, and
canal_protocol derives the HTTP contract from both. This module needs numpy only (no
scipy), so a client can validate options without loading the fitting code.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Literal, cast, get_args

from .cross_sections import KINDS_3D
from .errors import InvalidInputError
from .sections import section_kinds
from .validation import check_choice, check_fraction, check_int, check_positive

FrameKind = Literal["rmf", "frenet"]
#: "spline": resampled evenly in the clock's parameter (the paper); "warp": each demo then
#: warped onto their mean by DTW on at most 64 samples, the warp interpolated to N (the
#: default); "dtw": DTW on all N samples (cost N^2 per demo).
AlignmentKind = Literal["spline", "dtw", "warp"]
DirectrixKind = Literal["mean", "gmr"]
#: The built-in choices of ``cross_section`` ("interval" is the 2-D form of each and is not
#: chosen by name); kinds registered later are accepted by :func:`canal_core.fit.fit` too
#: (:func:`canal_core.sections.section_kinds` with dim=3 lists them all).
CROSS_SECTIONS: tuple[str, ...] = KINDS_3D
FRAMES: tuple[FrameKind, ...] = get_args(FrameKind)
ALIGNMENTS: tuple[AlignmentKind, ...] = get_args(AlignmentKind)
DIRECTRICES: tuple[DirectrixKind, ...] = get_args(DirectrixKind)
#: What a reproduction does with a start outside the canal (:meth:`Canal.reproduce_detailed`).
OutsideRule = Literal["project", "raise"]
OUTSIDE_RULES: tuple[OutsideRule, ...] = get_args(OutsideRule)
#: How a reproduction carries the start's offset along the canal
#: (:func:`canal_core.reproduce.learned_persistence`; docs/method.md section 4b).
Persistence = Literal["learned", "constant", "learned+end"]
PERSISTENCES: tuple[Persistence, ...] = get_args(Persistence)
#: Bounds of ``n_samples`` (N, the number of cross-sections) and of ``frame_smoothing``; the
#: service's limits are these. A fit's cost grows faster than N (5 demos of 1,000 points:
#: about 1 s at N = 5,000, 38 s at 20,000, over 7 min at 100,000, on a busy 2-core machine),
#: so N stops where a fit still answers within an HTTP request's patience.
MIN_SAMPLES = 2
MAX_SAMPLES = 5_000
MAX_FRAME_SMOOTHING = 0.25
#: Corrections (:mod:`canal_core.corrections`): their kinds, and how many samples one has.
CorrectionKind = Literal["include", "exclude"]
CORRECTION_KINDS: tuple[CorrectionKind, ...] = get_args(CorrectionKind)
MIN_CORRECTION_SAMPLES = 4
#: A few seconds of a 1 kHz stream.
MAX_CORRECTION_SAMPLES = 20_000
#: Routes (:mod:`canal_core.routes`): ``routes`` forces a number of routes in [1, MAX_ROUTES]
#: (each needs two demonstrations, so at most half of them); None clusters at
#: ``route_separation``, a share of the median path length in [MIN_ROUTE_SEPARATION,
#: MAX_ROUTE_SEPARATION].
MAX_ROUTES = 32
#: Measured on the sets of BENCHMARKS.md (canal_core.routes says where they split).
DEFAULT_ROUTE_SEPARATION = 0.25
#: Demonstrations closer than a hundredth of their length apart go one way by any measure: a
#: smaller cut makes a route of each (their noise), none with a width of its own.
MIN_ROUTE_SEPARATION = 0.01
MAX_ROUTE_SEPARATION = 4.0


@dataclass(frozen=True)
class FitOptions:
    """How a canal was fitted (see :func:`canal_core.fit.fit`)."""

    #: One of :data:`CROSS_SECTIONS`.
    cross_section: str = "circle"
    frames: FrameKind = "rmf"
    alignment: AlignmentKind = "warp"
    directrix: DirectrixKind = "mean"
    #: In [MIN_SAMPLES, MAX_SAMPLES].
    n_samples: int = 200
    #: Gaussian smoothing of the curve the frames are computed on, as a fraction of
    #: n_samples (0 = frames of the raw directrix, as in the paper). See canal_core.frames.
    frame_smoothing: float = 0.02

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def fit_options(
    cross_section: str = "circle",
    frames: str = "rmf",
    alignment: str = FitOptions.alignment,
    directrix: str = "mean",
    n_samples: int = 200,
    frame_smoothing: float = FitOptions.frame_smoothing,
) -> FitOptions:
    """Validated :class:`FitOptions`."""
    return FitOptions(
        cross_section=check_choice(cross_section, section_kinds(3), "cross_section"),
        frames=cast(FrameKind, check_choice(frames, FRAMES, "frames")),
        alignment=cast(AlignmentKind, check_choice(alignment, ALIGNMENTS, "alignment")),
        directrix=cast(DirectrixKind, check_choice(directrix, DIRECTRICES, "directrix")),
        n_samples=check_int(n_samples, MIN_SAMPLES, "n_samples", maximum=MAX_SAMPLES),
        frame_smoothing=check_fraction(frame_smoothing, "frame_smoothing",
                                       maximum=MAX_FRAME_SMOOTHING),
    )


def route_options(routes: int | None = None,
                  route_separation: float = DEFAULT_ROUTE_SEPARATION) -> tuple[int | None, float]:
    """Validated ``(routes, route_separation)``: how demonstrations are split into routes."""
    if routes is not None:
        routes = check_int(routes, 1, "routes", maximum=MAX_ROUTES)
    separation = check_positive(route_separation, "route_separation")
    if not MIN_ROUTE_SEPARATION <= separation <= MAX_ROUTE_SEPARATION:
        raise InvalidInputError(f"expected route_separation in [{MIN_ROUTE_SEPARATION}, "
                                f"{MAX_ROUTE_SEPARATION}], got {separation}",
                                field="route_separation")
    return routes, separation
