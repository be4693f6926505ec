"""Fitting a canal to demonstrations (Alg. 1 lines 1-6, ENCODING DEMONSTRATIONS).

:func:`fit` prepares the raw demonstrations (:mod:`canal_core.preprocess`), aligns them
(:mod:`canal_core.alignment`), takes their mean as the directrix (:mod:`canal_core.directrix`),
frames it (:mod:`canal_core.frames`), fits a cross-section to each plane's crossings
(:mod:`canal_core.cross_sections`) and grows the sections until every demonstrated sample is
inside (:mod:`canal_core.enclosing`); it returns a :class:`~canal_core.model.Canal`.
"""

from __future__ import annotations

from typing import Any, cast

import numpy as np

from .alignment import (
    DTW_SAMPLES,
    dtw_parameters,
    resampled_demonstrations,
    spline_parameter,
    splines_at,
)
from .clocks import TIMINGS, TimingChoice, alignment_parameters, chosen_clock, steady_index_clock
from .cross_sections import (
    CrossSections,
    fitted_sections,
    floored_sections,
    scaled_sections,
    section_kind,
)
from .crossings import in_plane_coordinates, located_crossings, sections_of_samples
from .directrix import directrix_gmr, directrix_mean
from .enclosing import enclosing_scales
from .errors import DegenerateCanalError, InvalidInputError
from .frames import canal_frames
from .model import Canal
from .options import FitOptions, fit_options
from .orientation import OrientationModel, fitted_orientations
from .preprocess import STILL_TOLERANCE, PreparedDemonstration, prepared_samples_many
from .reproduce import section_basis
from .timing import paced_phases, section_pace, section_times
from .validation import (
    FloatArray,
    check_choice,
    check_demonstration_orientations,
    check_demonstrations,
)


def end_depths(
    samples: FloatArray, phase: FloatArray, centres: FloatArray, tangents: FloatArray
) -> FloatArray:
    """How far demo samples (M, D) reach behind plane 0 and past plane N-1, shape (2,).

    Only samples in the first and last 5 % of their demo (by ``phase`` in [0, 1]) count,
    so a curve that loops back near its start later on does not stretch the canal.
    """
    behind = (np.take(samples, np.flatnonzero(phase < 0.05), axis=0) - centres[0]) @ tangents[0]
    past = (np.take(samples, np.flatnonzero(phase > 0.95), axis=0) - centres[-1]) @ tangents[-1]
    return np.array(
        [max(0.0, -float(behind.min(initial=0.0))), max(0.0, float(past.max(initial=0.0)))]
    )


def fit(
    demos: Any,
    timestamps: Any = None,
    cross_section: str = "circle",
    frames: str = "rmf",
    alignment: str = FitOptions.alignment,
    directrix: str = "mean",
    n_samples: int = 200,
    still_tolerance: float = STILL_TOLERANCE,
    frame_smoothing: float = FitOptions.frame_smoothing,
    orientations: Any = None,
    by_time: bool | None = None,
    timing: str = "auto",
) -> Canal:
    """Fit a canal surface to demonstrations (Alg. 1, ENCODING DEMONSTRATIONS).

    Parameters
    ----------
    demos : sequence of array_like, each shape (T_j, D)
        n >= 2 demonstrations, D in {2, 3}, T_j >= 4 (lengths may differ).
    timestamps : sequence of (array_like, shape (T_j,) or None), optional
        Seconds; raw logs are fine: every demo goes through
        :func:`canal_core.preprocess.prepared_demonstration` (repeats, rounding-level steps,
        glitches, still ends, equal or isolated out-of-order stamps). They give the canal its
        speed profile (``section_times``, :mod:`canal_core.timing`) and, unless ``by_time``
        is False, its alignment (see ``timing``).
    cross_section : {"circle", "mec", "ellipse", "spline"}
    frames : {"rmf", "frenet"}
    alignment : {"warp", "spline", "dtw"}
        "spline": every demo resampled evenly in the clock's parameter (see ``timing``), the
        paper's alignment; "warp" (default): each then matched to their mean by DTW on at
        most :data:`canal_core.alignment.DTW_SAMPLES` samples and resampled along that warp
        (the same rhythm at different paces is aligned at a small fixed cost); "dtw": the
        same DTW on all ``n_samples`` samples (cost grows as ``n_samples`` squared).
    directrix : {"mean", "gmr"}
    n_samples : int
        N, the number of cross-sections.
    frame_smoothing : float
        Frames are computed on the directrix smoothed by a Gaussian of this fraction of its
        length (0.02 by default; 0 = the paper's frames of the raw directrix). See
        :func:`canal_core.frames.length_smoothed_curve`.
    by_time : bool, optional
        True: ``timing="time"``; False: ``timing="arc"`` (the speed profile is kept either
        way); None: ``timing`` decides.
    timing : {"auto", "time", "index", "arc", "time+arc", "index+arc"}
        The clock the demonstrations are aligned by (:func:`canal_core.clocks.chosen_clock`):
        "auto" takes their time stamps, or without stamps their sample index when the
        logger's rate was steady, blended with arc length, when their rhythm is consistent
        by it; else arc length. The canal's ``clock`` says which was used.
    still_tolerance : float
        Head and tail samples within this fraction of the path length of the first/last
        sample are trimmed (see :mod:`canal_core.preprocess`).
    orientations : sequence of array_like, each shape (T_j, 4), optional
        Unit quaternions [qx, qy, qz, qw], one per position of each demo (q and -q alike).
        When given, the canal also learns a mean orientation and a spread per section on the
        positions' alignment (:mod:`canal_core.orientation`). Rows dropped with the position
        repeats and still ends are dropped here too.

    Returns
    -------
    Canal

    Raises
    ------
    InvalidInputError
        Malformed demonstrations, timestamps or options, coordinates beyond +-1e15, a demo
        that does not move; ``field`` names the demo (``demos[j]`` / ``timestamps[j]``).
    DegenerateCanalError
        Every demonstration identical, or a directrix of zero length.
    """
    options = fit_options(cross_section, frames, alignment, directrix, n_samples, frame_smoothing)
    asked = cast(TimingChoice, check_choice(timing, TIMINGS, "timing"))
    if by_time is not None:
        asked = "time" if by_time else "arc"
    demos_, times_, dim = check_demonstrations(demos, timestamps)
    quats_ = None if orientations is None else check_demonstration_orientations(orientations, demos_)
    min_demos = section_kind(options.cross_section).min_demos
    if dim == 3 and len(demos_) < min_demos:
        # Two crossings per plane fix one axis only (spline, ellipse): the other would be made up.
        raise InvalidInputError(
            f"expected at least {min_demos} demonstrations for {options.cross_section} cross-sections, "
            f"got {len(demos_)}; use circle or mec with 2",
            field="cross_section",
        )

    return _fitted_canal(demos_, times_, options, asked, quats_, still_tolerance)


def fit_lone(
    demo: Any,
    donor: Canal,
    timestamps: Any = None,
    orientations: Any = None,
    still_tolerance: float = STILL_TOLERANCE,
) -> Canal:
    """A canal for a route only one demonstration took: its own directrix, a borrowed envelope.

    A canal is the envelope of several demonstrations; one demonstration shows its route but
    not how far the person strays from it. The canal of a lone route is the demonstration
    itself as the directrix (resampled by ``donor``'s clock where it can be), framed as
    :func:`fit` frames one, with ``donor``'s sections scaled by the ratio of the two
    directrices' lengths, section for section,

        R_i^lone = (L^lone / L^donor) R_i^donor                                      (L1)

    then grown, as :func:`fit` grows any canal, until every sample of the demonstration is
    inside. ``donor`` is the route the demonstration would otherwise have joined
    (:func:`canal_core.routes.fit_routes`): the person's spread there is the best guess of
    their spread here. Its ``section_points`` are the demonstration's own crossings (on the
    directrix), so ``n_demos`` is 1 and the learned persistence, with no spread of offsets to
    read, leaves a start's ratio to the end decay (borrowing the donor's offsets as well
    follows LASA ``Multi_Models_1`` no closer).

    Parameters
    ----------
    demo : array_like, shape (T, D)
    donor : Canal
        Fitted to two demonstrations or more; its options (section kind, N, frames) are kept.
    timestamps : array_like, shape (T,), optional
    orientations : array_like, shape (T, 4), optional
        The demonstration's orientations: its canal's mean orientations, with the donor's
        offsets from its means (the spread, in radians, unscaled). Without them the canal
        has no orientation model, whatever the donor has.
    still_tolerance : float
        As :func:`fit`.
    """
    demos_, times_, dim = check_demonstrations([demo], None if timestamps is None else [timestamps],
                                               at_least=1)
    if dim != donor.dim:
        raise InvalidInputError(f"expected a demonstration of dimension {donor.dim} like its donor, "
                                f"got {dim}", field="demos")
    quats_ = None if orientations is None else check_demonstration_orientations([orientations], demos_)
    return _fitted_canal(demos_, times_, donor.options, cast(TimingChoice, donor.clock), quats_,
                         still_tolerance, donor=donor)


def _fitted_canal(
    demos_: list[FloatArray],
    times_: list[FloatArray | None],
    options: FitOptions,
    asked: TimingChoice,
    quats_: list[FloatArray] | None,
    still_tolerance: float,
    donor: Canal | None = None,
) -> Canal:
    """:func:`fit` on validated demonstrations; with ``donor``, :func:`fit_lone`."""
    # Timestamps are prepared (repaired or refused) even when the alignment is by arc
    # length: they still give the speed profile.
    prepared = prepared_samples_many(
        demos_, times_, [f"demos[{j}]" for j in range(len(demos_))],
        [f"timestamps[{j}]" for j in range(len(demos_))], still_tolerance=still_tolerance,
    )
    positions = [p.positions for p in prepared]
    stamped = [p.timestamps for p in prepared]
    # The index is a clock only for a steady logger without stamps (T2); its pace is kept.
    steady = all(t is None for t in stamped) and steady_index_clock(positions)
    clock = chosen_clock(positions, stamped, asked, steady)
    times = alignment_parameters(positions, stamped, clock)

    warps = None
    dim = demos_[0].shape[1]
    if options.alignment in ("dtw", "warp") and donor is None:
        warps = dtw_parameters(positions, times, options.n_samples,
                               resolution=DTW_SAMPLES if options.alignment == "warp" else None)
    pace = section_pace(positions, options.n_samples, times, warps) if steady else None
    if pace is not None and clock.startswith("index") and donor is None:  # (P2)
        phases = paced_phases(pace)
        even = np.linspace(0.0, 1.0, options.n_samples)
        read = np.tile(even, (len(positions), 1)) if warps is None else warps
        warps = np.vstack([np.interp(phases, even, row) for row in read])
        pace = section_pace(positions, options.n_samples, times, warps)
    if warps is None:
        aligned = resampled_demonstrations(positions, times, options.n_samples)
    else:
        aligned = splines_at(positions, times, warps)

    centres = directrix_gmr(aligned) if options.directrix == "gmr" else directrix_mean(aligned)
    steps = np.linalg.norm(np.diff(centres, axis=0), axis=1)
    arclength = np.concatenate([[0.0], np.cumsum(steps)])
    spread = max(float(aligned[..., d].max() - aligned[..., d].min()) for d in range(dim))
    if arclength[-1] <= 1e-12 * max(spread, 1e-300) or arclength[-1] == 0.0:
        raise DegenerateCanalError(
            "the directrix has zero length: the demonstrations do not move (or cancel out on average)",
            field="demos",
        )

    tangents, normals, binormals = canal_frames(centres, options)

    crossings, crossing_index = located_crossings(aligned, centres, tangents)
    # A demo that starts behind the first plane (or ends past the last) is measured at the
    # end section by its projected end sample, so the extruded ends hold the whole demo.
    for end, outward in ((0, -1.0), (-1, 1.0)):
        offset = (aligned[:, end] - centres[end]) @ tangents[end]
        beyond = outward * offset > 0.0
        crossings[end, beyond] = aligned[beyond, end] - offset[beyond, None] * tangents[end]
    basis = section_basis(normals, binormals)
    coords = in_plane_coordinates(crossings, centres, basis)
    if donor is not None:  # (L1)
        ratio = float(arclength[-1] / donor.arclength[-1])
        sections = scaled_sections(donor.sections, np.full(options.n_samples, ratio))
    else:
        sections = _crossing_sections(coords, arclength, centres, options)
    # Make the canal a true envelope of the demonstrated samples, not only of the crossings.
    # Every genuine sample counts, the trimmed still ends included (glitches do not); its
    # phase is its place in the prepared demonstration, 0 / 1 in the still ends.
    samples = np.vstack([np.take(d, p.sample_rows, axis=0) for d, p in zip(demos_, prepared, strict=True)])
    phase = np.concatenate([p.sample_phase for p in prepared])
    # Each sample starts its search at the sections its demo crosses there (not at its own
    # phase): demos ahead of or behind the mean are then found at once. A warped demo's
    # phase is first read through its warp (the aligned sample at that parameter).
    grid = np.arange(options.n_samples, dtype=np.float64)
    approx = np.rint(np.concatenate([
        sections_of_samples(crossing_index, j, p.sample_phase * (options.n_samples - 1) if warps is None
                            else np.interp(p.sample_phase, warps[j], grid))
        for j, p in enumerate(prepared)
    ])).astype(np.int64)
    enclosure = enclosing_scales(samples, approx, centres, tangents, basis, sections)
    sections = scaled_sections(sections, enclosure.scale)
    orientation = None
    if quats_ is not None:
        orientation = _fitted_orientation(prepared, times, quats_, options, warps)
        if donor is not None and donor.orientation is not None:
            # One demonstration has no spread of orientation either: the donor's, unscaled.
            orientation = OrientationModel(orientation.means, donor.orientation.offsets)
    return Canal(
        end_depths=np.maximum(end_depths(samples, phase, centres, tangents), enclosure.depths),
        section_times=section_times(positions, stamped, options.n_samples, times, warps),
        section_pace=pace,
        clock=clock,
        envelope_margin=float(enclosure.scale.max() - 1.0),
        directrix=centres,
        tangents=tangents,
        normals=normals,
        binormals=binormals,
        arclength=arclength,
        sections=sections,
        section_points=coords,
        options=options,
        orientation=orientation,
    )


def _crossing_sections(coords: FloatArray, arclength: FloatArray, centres: FloatArray,
                       options: FitOptions) -> CrossSections:
    """Sections fitted to the demonstrations' crossings (N, n, D - 1); a canal of no width is
    refused."""
    resolution = 1e-12 * arclength[-1]
    if not np.any(np.abs(coords) > resolution):
        apart = float(np.abs(coords).max())
        if apart <= 1e-14 * max(float(arclength[-1]), float(np.abs(centres).max())):  # rounding
            raise DegenerateCanalError(
                "every demonstration is identical: the canal has zero radius everywhere",
                field="demos")
        # Not identical: their differences are lost in the rounding of coordinates this large.
        raise DegenerateCanalError(
            f"the demonstrations are at most {apart:.3g} apart across the canal, below its "
            f"resolution of {resolution:.3g} (1e-12 of the directrix length {arclength[-1]:.3g}): "
            "at this scale they cannot be told apart; rescale the units, or demonstrate "
            "the variation", field="demos")
    size = float(np.abs(coords).max())
    return floored_sections(fitted_sections(coords, options.cross_section), 1e-9 * size)


def _fitted_orientation(
    prepared: list[PreparedDemonstration],
    times: list[FloatArray | None],
    quaternions: list[FloatArray],
    options: FitOptions,
    warps: FloatArray | None,
) -> OrientationModel:
    """The orientation model on the same alignment as the positions.

    Orientations follow the rows the preparation stage kept for their positions, at the
    spline parameter the positions were aligned by (``times``: the stamps, or None for arc
    length), read at the positions' warps (``warps``, (n, N)) or, without one, evenly.
    """
    positions = [p.positions for p in prepared]
    parameters = [spline_parameter(d, t) for d, t in zip(positions, times, strict=True)]
    if warps is not None:
        at = warps
    else:
        at = np.broadcast_to(np.linspace(0.0, 1.0, options.n_samples), (len(prepared), options.n_samples))
    return fitted_orientations([q[p.rows] for q, p in zip(quaternions, prepared, strict=True)], parameters, at)
