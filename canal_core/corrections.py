"""Corrections: a person refines a fitted canal locally with a short path (paper Section 6).

The paper leaves refinement to future work ("the model can be updated based on the physical
corrections from the user"). A correction is a short path over part of the canal with a kind:

``include``
    "This path is right too." In each section i the path crosses (in-plane point q_i, in the
    section's basis), the centre moves towards it by the share of one demonstration of weight
    w among the canal's n, and the section grows about the moved centre until it holds both
    its old boundary and q_i::

        delta_i = w / (n + w) * q_i                                         (C1)
        k_i     = max(1, max_{x in dS_i u {q_i}} |x - delta_i| / rho_i(x - delta_i))  (C2)

``exclude``
    "The robot was pushed away from where it went." In each section the push reaches, the
    direction d_i from the pushed point q_i towards the canal's own plan p_i (what the ratio
    rule would have done from the correction's first sample) is the excluded side; the
    section keeps its extent -rho_i(-d_i) on the other side and ends at h_i = q_i . d_i on
    this one. A star-shaped section cannot narrow on one side, so it is shrunk about its
    centre and shifted along d_i to fill that extent::

        k_i     = (h_i + rho_i(-d_i)) / (rho_i(d_i) + rho_i(-d_i))          (C3)
        delta_i = (h_i - k_i rho_i(d_i)) d_i                                (C4)

    For a circle of radius r this is the largest circle in the segment x . d <= h:
    radius (r + h) / 2 about the centre shifted by (h - r) / 2 along d. A section that
    would keep less than :data:`MIN_WIDTH_FRACTION` of its width is refused (the canal would
    close); one the push does not cut (h_i >= rho_i(d_i)) is unchanged.

Either way the corrected section is S'_i = delta_i + k_i S_i (centre c'_i = c_i + B_i^T delta_i),
so every reproduction, the tracker and its compiled kernel use it with no change: the ratio
rule carries the ratio in the corrected sections. Over a short blend on each side of the span,
delta and k fade (smootherstep) to 0 and 1; outside the span and its blend every array of the
canal is the parent's, bit for bit. The blend is long enough to keep the directrix's slope
gentle, but never longer than :data:`LONGEST_BLEND_FACTOR` times the default one (9 % of the
sections, at least 9): a larger shift is blended more steeply rather than over more of the
canal (:func:`locally_moved`, B1 and B2). Demonstrated samples an exclude's blend leaves outside
are marked excluded as those in its span are (:func:`blend_dropped_crossings` says which
crossings). Frames in the changed range are carried by double
reflection from the frame before it, and the twist they pick up is unwound over the trailing
blend, so the frame after it is the parent's again (rotation-minimising frames would otherwise
carry the twist to the end of the canal).

Demonstrated samples on the excluded side of a cut are outside the corrected canal by the
person's choice: :func:`excluded_points` says which points are, and
:attr:`~canal_core.model.Canal.exempt_crossings` which demo crossings.

Where it fails: the cut is a straight line in each section, so a keep-out region seen from
several sides needs one correction per side; a correction longer than the canal's bends is
read by its first forward crossing of each plane (a path that loops back is read once);
frames are re-propagated, so a large include shift over a tight bend tilts the planes in the
span (their in-plane shapes are kept as they are).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from .cross_sections import CrossSections, boundary_distance
from .errors import InvalidInputError, ModelFormatError
from .frames import double_reflection_matrices, smoothed_curve
from .options import (
    CORRECTION_KINDS,
    MAX_CORRECTION_SAMPLES,
    MIN_CORRECTION_SAMPLES,
    CorrectionKind,
)
from .preprocess import check_time_order, glitch_rows
from .reproduce import (
    CONTAINS_TOLERANCE,
    located_points,
    section_basis,
    smootherstep,
    unit_directions,
)
from .validation import (
    BoolArray,
    FloatArray,
    IntArray,
    check_choice,
    check_positions,
    check_positive,
    check_quaternions,
    check_timestamps,
)

if TYPE_CHECKING:
    from .model import Canal

#: Fewest sections a correction must cross.
MIN_SPAN_SECTIONS = 2
#: A crossing farther than this many section radii from the directrix is not over the canal.
REACH = 3.0
#: An exclude correction must leave at least this fraction of a section's width.
MIN_WIDTH_FRACTION = 0.1
#: An exclude reaches a section where the push moved the path at least this fraction of
#: the section's radius away from the plan.
PUSH_THRESHOLD = 0.1
#: Blend on each side of the span: this fraction of the sections, at least MIN_BLEND.
BLEND_FRACTION = 0.03
MIN_BLEND = 3
#: Relative margin by which an include section holds the path (planes tilt a little).
INCLUDE_MARGIN = 0.01
#: Steepest slope of the directrix's displacement over a blend (the blend grows with the
#: shift to keep it, up to LONGEST_BLEND_FACTOR times); smootherstep's steepest slope is 15/8 of its mean.
MAX_BLEND_SLOPE = 0.2
SMOOTHERSTEP_SLOPE = 1.875
#: Longest blend on each side of a span: this many times the default one (:func:`blend_width`).
#: A shift too large for MAX_BLEND_SLOPE within it is blended more steeply, never over more of
#: the canal.
LONGEST_BLEND_FACTOR = 3
#: Sections past each end of an include's path that hold its end crossing (the path ends
#: between planes, which the span's moved planes tilt).
END_PAD = 2
#: Relative margin by which a grown section holds its parent's boundary.
HOLD_MARGIN = 1e-3
#: Boundary directions sampled when growing a section around its old boundary.
BOUNDARY_SAMPLES = 64
#: Points times sections per block when a correction locates many points at once (path
#: crossings, dropped demo crossings): keeps their tables within a few MB.
LOCATE_BLOCK = 1 << 18


@dataclass(frozen=True, eq=False)
class Correction:
    """What a person showed.

    Attributes
    ----------
    kind : {"include", "exclude"}
    samples : array, shape (M, D)
        The corrected path, in order along the canal.
    weight : float
        How much an include counts against one demonstration (C1); exclude ignores it.
    label : str
    timestamps : array, shape (M,), or None
        Kept with the correction; the geometry does not use them.
    orientations : array, shape (M, 4), or None
        Kept with the correction; the geometry does not use them.
    plan : array, shape (P, D), or None
        Exclude: the path the robot was on before the push (a live tracker's constant
        ratio, say); the canal's own reproduction from the first sample when None.
    """

    kind: str
    samples: FloatArray
    weight: float = 1.0
    label: str = ""
    timestamps: FloatArray | None = None
    orientations: FloatArray | None = None
    plan: FloatArray | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "samples": self.samples.tolist(),
            "weight": self.weight,
            "label": self.label,
            "timestamps": None if self.timestamps is None else self.timestamps.tolist(),
            "orientations": None if self.orientations is None else self.orientations.tolist(),
            "plan": None if self.plan is None else self.plan.tolist(),
        }


@dataclass(frozen=True, eq=False)
class AppliedCorrection:
    """A correction as applied to one canal: the sections it changed and, for exclude, its cuts.

    Attributes
    ----------
    correction : Correction
    first, last : int
        The corrected span (sections first..last, inclusive).
    lo, hi : int
        The changed range: the span and its blend.
    cut_points, cut_directions : arrays, shape (last - first + 1, D), or None
        Exclude only: a point on each section's cut and the unit direction of the excluded
        side (world coordinates; NaN rows where the push did not cut the section).
    before : dict or None
        The parent's directrix, tangents, basis and section parameters over lo - 1..hi + 1
        (:func:`parent_rows`): the canal before the correction where it changed. For an
        exclude, what lay inside them and lies outside the corrected canal was excluded by
        the person.
    """

    correction: Correction
    first: int
    last: int
    lo: int
    hi: int
    cut_points: FloatArray | None = None
    cut_directions: FloatArray | None = None
    before: dict[str, Any] | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            **self.correction.to_dict(),
            "first": self.first,
            "last": self.last,
            "lo": self.lo,
            "hi": self.hi,
            "cut_points": None if self.cut_points is None else _nan_list(self.cut_points),
            "cut_directions": None if self.cut_directions is None else _nan_list(self.cut_directions),
            "before": None if self.before is None else {
                "directrix": self.before["directrix"].tolist(),
                "tangents": self.before["tangents"].tolist(),
                "basis": self.before["basis"].tolist(),
                "sections": {k: v.tolist() for k, v in self.before["sections"].items()},
            },
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any], n_sections: int, dim: int) -> AppliedCorrection:
        """Rebuild one written by :meth:`to_dict`; raises :class:`ModelFormatError`."""
        try:
            correction = Correction(
                kind=check_choice(data["kind"], CORRECTION_KINDS, "kind"),
                samples=np.asarray(data["samples"], dtype=np.float64).reshape(-1, dim),
                weight=float(data.get("weight", 1.0)),
                label=str(data.get("label", "")),
                timestamps=_optional_array(data.get("timestamps")),
                orientations=_optional_array(data.get("orientations")),
                plan=None if data.get("plan") is None else np.asarray(data["plan"], dtype=np.float64).reshape(-1, dim),
            )
            first, last, lo, hi = (int(data[k]) for k in ("first", "last", "lo", "hi"))
            if not 0 <= lo <= first <= last <= hi < n_sections:
                raise ModelFormatError(
                    f"expected 0 <= lo <= first <= last <= hi < {n_sections}, got {lo}, {first}, {last}, {hi}",
                    field="corrections",
                )
            cuts = [_optional_array(data.get(k)) for k in ("cut_points", "cut_directions")]
            for cut in cuts:
                if cut is not None and cut.shape != (last - first + 1, dim):
                    raise ModelFormatError(
                        f"expected cuts of shape ({last - first + 1}, {dim}), got {cut.shape}", field="corrections"
                    )
            raw = data.get("before")
            before: dict[str, Any] | None = None
            if raw is not None:
                rows = len(raw["directrix"])
                before = {k: np.asarray(raw[k], dtype=np.float64) for k in ("directrix", "tangents", "basis")}
                before["sections"] = {k: np.asarray(v, dtype=np.float64) for k, v in raw["sections"].items()}
                if before["directrix"].shape != (rows, dim) or before["basis"].shape != (rows, dim - 1, dim):
                    raise ModelFormatError(f"expected {rows} rows before the correction, of dimension {dim}",
                                           field="corrections")
            return cls(correction, first, last, lo, hi, cuts[0], cuts[1], before)
        except (ModelFormatError, InvalidInputError) as exc:
            raise ModelFormatError(f"malformed correction: {exc.message}", field="corrections") from exc
        except (KeyError, TypeError, ValueError) as exc:
            raise ModelFormatError(f"malformed correction: {exc!r}", field="corrections") from exc


def _nan_list(values: FloatArray) -> list[list[float | None]]:
    """Rows as JSON lists, NaN as None (JSON has no NaN)."""
    return [[None if np.isnan(v) else float(v) for v in row] for row in values]


def _optional_array(values: Any) -> FloatArray | None:
    if values is None:
        return None
    return np.asarray([[np.nan if v is None else v for v in row] if isinstance(row, list) else row
                       for row in values], dtype=np.float64)


# -- input -------------------------------------------------------------------------------


def checked_correction(
    kind: Any,
    samples: Any,
    dim: int,
    weight: Any = 1.0,
    label: Any = "",
    timestamps: Any = None,
    orientations: Any = None,
    plan: Any = None,
) -> Correction:
    """A validated :class:`Correction` for a ``dim``-D canal; raises :class:`InvalidInputError`.

    Parameters
    ----------
    kind : {"include", "exclude"}
    samples : array_like, shape (M, D)
        MIN_CORRECTION_SAMPLES <= M <= MAX_CORRECTION_SAMPLES.
    weight : float
        > 0.
    timestamps : array_like, shape (M,), optional
    orientations : array_like, shape (M, 4), optional
    plan : array_like, shape (P, D), optional
        Exclude only: the path the robot was on before the push (an include with one is
        refused naming ``plan``).
    """
    check_choice(kind, CORRECTION_KINDS, "kind")
    points = check_positions(samples, "samples", dim)
    if points.shape[0] > MAX_CORRECTION_SAMPLES:
        raise InvalidInputError(
            f"expected at most {MAX_CORRECTION_SAMPLES} samples, got {points.shape[0]}", field="samples"
        )
    if not isinstance(label, str) or len(label) > 200:
        raise InvalidInputError(f"expected label as text of at most 200 characters, got {label!r:.60}", field="label")
    times = None if timestamps is None else check_timestamps(timestamps, points.shape[0], "timestamps")
    if times is not None:
        check_time_order(times, "timestamps")
    quats = None if orientations is None else check_quaternions(orientations, points.shape[0], "orientations")
    if plan is not None and kind != "exclude":
        # A plan is where an exclude's push started from; an include has none to read.
        raise InvalidInputError(f"expected no plan on an {kind} correction (a plan is the path the robot "
                                "was on before an exclude's push), got a plan", field="plan")
    path = None if plan is None else check_positions(plan, "plan", dim)
    return Correction(str(kind), points, check_positive(weight, "weight"), label, times, quats, path)


def correction_glitches(samples: Any) -> BoolArray:
    """The samples of a correction path left out as glitches: a demonstration's rule
    (:func:`canal_core.preprocess.glitch_rows`, docs/preprocessing.md step 4) on the path in
    the order it came.

    Parameters
    ----------
    samples : array_like, shape (M, D)

    Returns
    -------
    glitch : array of bool, shape (M,)
    """
    return glitch_rows(check_positions(samples, "samples"))


def cleaned_samples(samples: FloatArray) -> FloatArray:
    """A correction path without its glitches (:func:`correction_glitches`), what shapes the
    canal; raises :class:`InvalidInputError` when fewer than ``MIN_CORRECTION_SAMPLES``
    samples are left, as a fit refuses a demonstration left too short."""
    glitch = glitch_rows(samples)
    if not glitch.any():
        return samples
    left = int(samples.shape[0] - glitch.sum())
    if left < MIN_CORRECTION_SAMPLES:
        raise InvalidInputError(
            f"expected at least {MIN_CORRECTION_SAMPLES} samples in samples, got {left} after "
            f"dropping {int(glitch.sum())} as glitches (far off the path and straight back)",
            field="samples",
        )
    return np.asarray(samples[~glitch], dtype=np.float64)


# -- geometry ----------------------------------------------------------------------------


def blend_width(n_sections: int) -> int:
    """Sections of blend on each side of a corrected span."""
    return max(MIN_BLEND, round(BLEND_FRACTION * n_sections))


def longest_blend(n_sections: int) -> int:
    """Most sections of blend on each side of a corrected span (B2): a correction changes at
    most its span and this many sections either side, whatever its shift."""
    return LONGEST_BLEND_FACTOR * blend_width(n_sections)


def path_crossings(
    path: FloatArray, centres: FloatArray, tangents: FloatArray, basis: FloatArray, reach: FloatArray
) -> tuple[BoolArray, FloatArray]:
    """Where a path first crosses each section plane forwards, near the section.

    A path that runs against the canal (more of its crossings near the sections go from the
    end towards the start) is read reversed: where it lies does not depend on the direction
    a person moved the arm to show it.

    Parameters
    ----------
    path : array, shape (M, D)
    centres, tangents : arrays, shape (N, D)
    basis : array, shape (N, D - 1, D)
    reach : array, shape (N,)
        Largest in-plane distance from c_i at which a crossing counts.

    Returns
    -------
    crossed : array of bool, shape (N,)
    coords : array, shape (N, D - 1)
        In-plane coordinates of the crossing (0 where not crossed).
    """
    n, m = centres.shape[0], path.shape[0]
    offsets = np.einsum("nd,nd->n", centres, tangents)
    # The samples' distances to every plane, a block of rows at a time (blocks share their
    # edge sample, so each step is in one): memory stays bounded for the longest path on the
    # finest canal, and only the crossings near their section are kept.
    rows = max(2, LOCATE_BLOCK // max(n, 1))
    ahead: list[tuple[IntArray, IntArray, FloatArray]] = []
    behind: list[tuple[IntArray, IntArray, FloatArray]] = []
    for lo in range(0, max(m - 1, 1), rows - 1):
        hi = min(lo + rows, m)
        part = path[lo:hi]
        dist = part @ tangents.T - offsets[None, :]  # (hi - lo, N)
        s, sec, c = _near_crossings(part, dist, centres, basis, reach)
        ahead.append((s + lo, sec, c))
        s, sec, c = _near_crossings(part[::-1], dist[::-1], centres, basis, reach)
        behind.append((s + (m - hi), sec, c))
    step, section, coords = _joined(ahead, basis.shape[1])
    backwards = _joined(behind, basis.shape[1])
    if backwards[0].size > step.size:
        # More of them backwards: the path read from its last sample to its first.
        step, section, coords = backwards
    # The first forward crossing of each plane, along the path.
    order = np.lexsort((step, section))
    section, coords = section[order], coords[order]
    keep = np.ones(section.size, dtype=bool)
    keep[1:] = section[1:] != section[:-1]
    crossed = np.zeros(n, dtype=bool)
    crossed[section[keep]] = True
    out = np.zeros((n, basis.shape[1]))
    out[section[keep]] = coords[keep]
    return crossed, out


def _joined(parts: list[tuple[IntArray, IntArray, FloatArray]], k: int
            ) -> tuple[IntArray, IntArray, FloatArray]:
    """The crossings of every block as one (steps, sections, coords (C, k))."""
    if not parts:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, k))
    return (np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]),
            np.concatenate([p[2] for p in parts]))


def _near_crossings(path: FloatArray, dist: FloatArray, centres: FloatArray, basis: FloatArray,
                    reach: FloatArray) -> tuple[IntArray, IntArray, FloatArray]:
    """The forward plane crossings of ``path`` (M, D) within ``reach`` of their section
    (``dist``: the samples' signed distances to every plane, (M, N)): the step before each
    (along ``path``), its section and its in-plane coordinates (C, D - 1)."""
    # Only the sign changes are interpolated: memory grows with the crossings, not M x N.
    step, section = np.nonzero((dist[:-1] <= 0.0) & (dist[1:] > 0.0))
    before, after = dist[step, section], dist[step + 1, section]
    points = path[step] + (before / (before - after))[:, None] * (path[step + 1] - path[step])
    coords = np.einsum("ckd,cd->ck", basis[section], points - centres[section])
    near = np.linalg.norm(coords, axis=1) <= reach[section]
    return step[near], section[near], coords[near]


def _span(crossed: BoolArray, field: str, path: FloatArray | None = None,
          spacing: float = 0.0) -> tuple[int, int]:
    hit = np.flatnonzero(crossed)
    noun, move = ("samples", "move") if field == "samples" else (f"a {field}", "moves")
    if hit.size == 0 and path is not None:
        spread = float(np.max(np.linalg.norm(path - path[0], axis=1)))
        if spread < spacing:
            # No plane is crossed because the path does not move, wherever it is.
            raise InvalidInputError(
                f"expected {noun} that {move} along the canal (across at least "
                f"{MIN_SPAN_SECTIONS} sections), got {field} within {spread:.3g} of one point, "
                f"less than one section's spacing ({spacing:.3g})", field=field)
    if hit.size == 0:
        raise InvalidInputError(
            f"expected {noun} over the canal (crossing section planes within "
            f"{REACH:g} radii of the directrix), got a path outside every section", field=field
        )
    first, last = int(hit[0]), int(hit[-1])
    if last - first + 1 < MIN_SPAN_SECTIONS:
        raise InvalidInputError(
            f"expected {noun} across at least {MIN_SPAN_SECTIONS} sections, got {last - first + 1}", field=field
        )
    return first, last


def _filled(crossed: BoolArray, coords: FloatArray, first: int, last: int) -> FloatArray:
    """In-plane coords over first..last, gaps linearly interpolated by section index."""
    idx = np.arange(first, last + 1)
    hit = np.flatnonzero(crossed[first : last + 1]) + first
    return np.stack([np.interp(idx, hit, coords[hit, k]) for k in range(coords.shape[1])], axis=1)


def _distance(sections: CrossSections, index: IntArray, direction: FloatArray) -> FloatArray:
    return boundary_distance(sections, index, direction)


def _held_scales(
    canal: Canal, lo: int, shift: FloatArray, new_centres: FloatArray, new_basis: FloatArray,
    extra: FloatArray | None,
) -> FloatArray:
    """Scales k (S,) about the moved centres so each moved section holds its parent's boundary
    and the ``extra`` world points (S, D, NaN rows: none), both read in the moved planes (C2)."""
    s = shift.shape[0]
    index = np.arange(lo, lo + s)
    if canal.dim == 2:
        dirs = np.array([[1.0], [-1.0]])
    else:
        angles = np.linspace(0.0, 2.0 * np.pi, BOUNDARY_SAMPLES, endpoint=False)
        dirs = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    a = dirs.shape[0]
    rim = _distance(canal.sections, np.repeat(index, a), np.tile(dirs, (s, 1)))[:, None] * np.tile(dirs, (s, 1))
    world = canal.directrix[index, None, :] + np.einsum("sak,skd->sad", rim.reshape(s, a, -1), canal.basis[index])
    if extra is not None:
        world = np.concatenate([world, extra[:, None, :]], axis=1)
    rel = np.einsum("skd,sad->sak", new_basis[index], world - new_centres[index, None, :])
    norm = np.linalg.norm(rel, axis=2)
    unit = rel / np.where(norm > 0.0, norm, 1.0)[:, :, None]
    unit[norm == 0.0] = dirs[0]
    m = rel.shape[1]
    rho = _distance(canal.sections, np.repeat(index, m), unit.reshape(s * m, -1)).reshape(s, m)
    need = np.where(rho > 0.0, norm / np.where(rho > 0.0, rho, 1.0), np.where(norm > 0.0, np.inf, 0.0))
    need = np.where(np.isnan(need), 0.0, need)
    # A little more than enough: a sample on the parent's boundary between an unchanged
    # plane and a tilted one is read against their blend.
    return np.maximum(1.0, need.max(axis=1) * (1.0 + HOLD_MARGIN))


def exclude_geometry(
    canal: Canal, pushed: FloatArray, planned: FloatArray, first: int
) -> tuple[FloatArray, FloatArray, FloatArray, BoolArray]:
    """Shifts delta (S, D - 1), scales k (S,), cut directions d (S, D - 1) and which sections
    are cut (S,) of an exclude over sections first.. (C3, C4).

    Raises :class:`InvalidInputError` (field ``kind``) when a section would keep less than
    :data:`MIN_WIDTH_FRACTION` of its width.
    """
    s = pushed.shape[0]
    index = np.arange(first, first + s)
    away = planned - pushed
    gap = np.linalg.norm(away, axis=1)
    d = away / np.where(gap > 0.0, gap, 1.0)[:, None]
    d[gap == 0.0, 0] = 1.0
    forward = _distance(canal.sections, index, d)
    backward = _distance(canal.sections, index, -d)
    h = np.einsum("sk,sk->s", pushed, d)
    radius = canal.radii[index]
    cut = (gap > PUSH_THRESHOLD * radius) & (h < forward)
    width = forward + backward
    k = np.where(cut, (h + backward) / np.where(width > 0.0, width, 1.0), 1.0)
    if np.any(cut & (k < MIN_WIDTH_FRACTION)):
        worst = int(np.argmin(np.where(cut, k, np.inf)))
        raise InvalidInputError(
            f"expected an exclude correction that leaves at least {MIN_WIDTH_FRACTION:.0%} of each section's "
            f"width, got {max(float(k[worst]), 0.0):.1%} at section {first + worst}: the pushed path runs "
            "along the far side of the canal, so excluding the side it was pushed from would close the canal",
            field="kind",
        )
    shift = np.where(cut, h - k * forward, 0.0)[:, None] * d
    return shift, k, d, cut


def planned_coords(canal: Canal, samples: FloatArray, reach: FloatArray) -> tuple[BoolArray, FloatArray]:
    """Where the canal's own plan from the correction's first sample crosses each section."""
    plan = canal.reproduce(samples[0])
    return path_crossings(plan, canal.directrix, canal.tangents, canal.basis, reach)


def _ramp(n: int, first: int, last: int, blend: int) -> tuple[int, int, FloatArray]:
    """Changed range lo..hi and weights w (hi - lo + 1,): 1 over the span, smootherstep to 0."""
    lo, hi = max(0, first - blend), min(n - 1, last + blend)
    idx = np.arange(lo, hi + 1, dtype=np.float64)
    lead = smootherstep((idx - (first - blend - 1)) / (blend + 1))
    trail = smootherstep(((last + blend + 1) - idx) / (blend + 1))
    return lo, hi, np.minimum(lead, trail)


def _rotated(vectors: FloatArray, axes: FloatArray, angles: FloatArray) -> FloatArray:
    """Rodrigues: rotate each vector (K, 3) about its unit axis (K, 3) by its angle (K,)."""
    c, s = np.cos(angles)[:, None], np.sin(angles)[:, None]
    dot = np.einsum("kd,kd->k", axes, vectors)[:, None]
    return vectors * c + np.cross(axes, vectors) * s + axes * dot * (1.0 - c)


def moved_frames(
    canal: Canal, centres: FloatArray, lo: int, hi: int, last: int
) -> tuple[FloatArray, FloatArray, FloatArray | None]:
    """Tangents, normals and binormals of the moved directrix, changed in lo..hi only.

    Tangents add the derivative of the (smoothed) displacement along the arc length to the
    parent's; normals are carried by double reflection from the frame before lo, and the
    twist they reach at hi + 1 is unwound over the trailing blend (last + 1 .. hi).
    """
    n = canal.n_sections
    sigma = canal.options.frame_smoothing * canal.options.n_samples
    pad = max(1, int(np.ceil(4.0 * sigma))) + 1
    a, b = max(0, lo - pad), min(n - 1, hi + pad)
    moved = centres[a : b + 1] - canal.directrix[a : b + 1]
    smooth = smoothed_curve(moved, sigma)
    steps = np.gradient(canal.arclength[a : b + 1])
    slope = np.gradient(smooth, axis=0) / np.maximum(steps, 1e-300)[:, None]
    tangents = canal.tangents.copy()
    t = canal.tangents[lo : hi + 1] + slope[lo - a : hi - a + 1]
    tangents[lo : hi + 1] = t / np.linalg.norm(t, axis=1, keepdims=True)
    normals = canal.normals.copy()
    if canal.binormals is None:
        tt = tangents[lo : hi + 1]
        normals[lo : hi + 1] = np.column_stack([-tt[:, 1], tt[:, 0]])
        return tangents, normals, None
    start = max(lo - 1, 0)
    end = min(hi + 1, n - 1)
    pts = centres[start : end + 1]
    tan = tangents[start : end + 1]
    r0 = canal.normals[start] - (canal.normals[start] @ tan[0]) * tan[0]
    r0 /= np.linalg.norm(r0)
    carried = np.empty_like(tan)
    carried[0] = r0
    for j, rot in enumerate(double_reflection_matrices(pts, tan)):
        carried[j + 1] = rot @ carried[j]
    carried -= np.einsum("kd,kd->k", carried, tan)[:, None] * tan
    carried /= np.linalg.norm(carried, axis=1, keepdims=True)
    if end == hi + 1:  # unwind the twist so that frame hi + 1 is the parent's again
        got, want, axis = carried[-1], canal.normals[end], tangents[end]
        twist = float(np.arctan2(np.cross(got, want) @ axis, got @ want))
        idx = np.arange(start, end + 1, dtype=np.float64)
        share = smootherstep((idx - last) / max(end - last, 1))
        carried = _rotated(carried, tan, twist * share)
        carried -= np.einsum("kd,kd->k", carried, tan)[:, None] * tan
        carried /= np.linalg.norm(carried, axis=1, keepdims=True)
    keep = slice(lo - start, hi - start + 1)
    normals[lo : hi + 1] = carried[keep]
    binormals = canal.binormals.copy()
    binormals[lo : hi + 1] = np.cross(tangents[lo : hi + 1], normals[lo : hi + 1])
    return tangents, normals, binormals


def locally_moved(
    canal: Canal,
    first: int,
    last: int,
    shift: FloatArray,
    scale: FloatArray | None,
    blend: int,
    held: FloatArray | None = None,
) -> tuple[Canal, int, int]:
    """The canal with sections first..last moved by ``shift`` (S, D - 1, in-plane) and scaled
    by ``scale`` (S,) about their moved centres, faded out over a blend each side.

    The blend has ``blend`` sections, or more where the shift at the span's edge needs them to
    keep the directrix's slope below :data:`MAX_BLEND_SLOPE` (B1), and never more than
    :func:`longest_blend` (B2; docs/method.md section 5b)::

        b = min(max(blend, ceil(15/8 |delta_edge| / (MAX_BLEND_SLOPE * ds))), longest_blend(N))   (B1, B2)

    where ds is the median section spacing. A shift that B2 cuts short is blended more steeply
    (the planes in the blend tilt more); the change never reaches farther along the canal.

    ``scale`` None: grow each section of the changed range just enough to hold its parent's
    boundary and the world points ``held`` (S, D) of the span (C2).

    Returns the new canal and the changed range (lo, hi); every array outside it is the
    parent's, bit for bit.
    """
    n = canal.n_sections
    # A blend long enough that the directrix's slope over it stays gentle (planes tilt by
    # at most about atan(MAX_BLEND_SLOPE)), but local: an exclude keeps one wall and cuts at
    # the pushed line, so its shift at the span's edge is about half a radius or more however
    # gently the push began, and a blend sized for that alone could cover the whole canal.
    step = float(np.median(np.diff(canal.arclength))) if n > 1 else 1.0
    edge_shift = max(float(np.linalg.norm(shift[0])), float(np.linalg.norm(shift[-1])))
    gentle = int(np.ceil(SMOOTHERSTEP_SLOPE * edge_shift / (MAX_BLEND_SLOPE * max(step, 1e-300))))
    blend = max(blend, min(gentle, longest_blend(n)))
    lo, hi, w = _ramp(n, first, last, blend)
    idx = np.arange(lo, hi + 1)
    edge = np.clip(idx, first, last) - first
    shift_full = w[:, None] * shift[edge]
    basis = canal.basis
    centres = canal.directrix.copy()
    centres[lo : hi + 1] = canal.directrix[lo : hi + 1] + np.einsum("sk,skd->sd", shift_full, basis[lo : hi + 1])
    tangents, normals, binormals = moved_frames(canal, centres, lo, hi, last)
    new_basis = section_basis(normals, binormals)
    if scale is None:
        extra = None
        if held is not None:
            extra = np.full((hi - lo + 1, canal.dim), np.nan)
            extra[first - lo : last - lo + 1] = held
        scale_full = _held_scales(canal, lo, shift_full, centres, new_basis, extra)
    else:
        scale_full = 1.0 + w * (scale[edge] - 1.0)
    # Sections: scaled rows in lo..hi, the parent's rows elsewhere.
    factor = np.ones(n)
    factor[lo : hi + 1] = scale_full
    scaled = canal.sections.spec.scaled(canal.sections, factor)
    params = {}
    for name, old in canal.sections.params.items():
        new = old.copy()
        new[lo : hi + 1] = scaled.params[name][lo : hi + 1]
        params[name] = new
    sections = CrossSections(canal.sections.kind, params)
    # Demo crossings keep their place in space, read in the moved planes.
    points = canal.section_points.copy()
    world = canal.directrix[lo : hi + 1, None, :] + np.einsum(
        "snk,skd->snd", canal.section_points[lo : hi + 1], basis[lo : hi + 1]
    )
    points[lo : hi + 1] = np.einsum("skd,snd->snk", new_basis[lo : hi + 1], world - centres[lo : hi + 1, None, :])
    # Arc length: the moved steps, rescaled to the parent's length over the changed range.
    arclength = canal.arclength.copy()
    a, b = max(lo - 1, 0), min(hi + 1, n - 1)
    steps = np.linalg.norm(np.diff(centres[a : b + 1], axis=0), axis=1)
    total = canal.arclength[b] - canal.arclength[a]
    if steps.sum() > 0.0 and b > a:
        inner = canal.arclength[a] + np.cumsum(steps) * (total / steps.sum())
        arclength[a + 1 : b] = inner[:-1]
    moved = replace(
        canal, directrix=centres, tangents=tangents, normals=normals, binormals=binormals,
        arclength=arclength, sections=sections, section_points=points,
    )
    return moved, lo, hi


def parent_rows(canal: Canal, lo: int, hi: int) -> dict[str, Any]:
    """The parent's geometry over lo..hi: the canal before a correction where it changed (what
    an exclude removed is measured against it)."""
    return {
        "directrix": canal.directrix[lo : hi + 1].copy(),
        "tangents": canal.tangents[lo : hi + 1].copy(),
        "basis": canal.basis[lo : hi + 1].copy(),
        "sections": {k: v[lo : hi + 1].copy() for k, v in canal.sections.params.items()},
    }


def corrected_canal(canal: Canal, correction: Correction, plan: FloatArray | None = None) -> Canal:
    """A new canal: ``canal`` refined by ``correction``; its parent is ``canal``.

    Parameters
    ----------
    canal : Canal
    correction : Correction
        From :func:`checked_correction`.
    plan : array, shape (P, D), optional
        Exclude: the path the robot was on before the push; the canal's own reproduction
        from the correction's first sample when None.

    Raises
    ------
    InvalidInputError
        ``samples``: wrong dimension, too short (glitches left out), outside every section; ``plan``:
        outside every section or off the samples' sections; ``kind``: an exclude that would close
        the canal.
    """
    # Glitches (one reading far off the path) are left out, as a demonstration's are at fit.
    samples = cleaned_samples(check_positions(correction.samples, "samples", canal.dim))
    reach = REACH * canal.radii
    crossed, coords = path_crossings(samples, canal.directrix, canal.tangents, canal.basis, reach)
    first, last = _span(crossed, "samples", samples, float(np.median(np.diff(canal.arclength))))
    blend = blend_width(canal.n_sections)
    if correction.kind == "include":
        pushed = _filled(crossed, coords, first, last)
        index = np.arange(first, last + 1)
        held = canal.directrix[index] + np.einsum("sk,skd->sd", (1.0 + INCLUDE_MARGIN) * pushed, canal.basis[index])
        # The path's ends lie between a span plane and the next one out: those sections hold
        # the end crossings too.
        lead, trail = min(first, END_PAD), min(canal.n_sections - 1 - last, END_PAD)
        first, last = first - lead, last + trail
        pushed = np.concatenate([pushed[:1]] * lead + [pushed] + [pushed[-1:]] * trail)
        held = np.concatenate([held[:1]] * lead + [held] + [held[-1:]] * trail)
        shift = correction.weight / (canal.n_demos + correction.weight) * pushed
        moved, lo, hi = locally_moved(canal, first, last, shift, None, blend, held)
        applied = AppliedCorrection(correction, first, last, lo, hi, before=parent_rows(
            canal, max(lo - 1, 0), min(hi + 1, canal.n_sections - 1)))
    else:
        plan = correction.plan if plan is None else plan
        if plan is None:
            p_crossed, p_coords = planned_coords(canal, samples, reach)
        else:
            path = check_positions(plan, "plan", canal.dim)
            p_crossed, p_coords = path_crossings(path, canal.directrix, canal.tangents, canal.basis, reach)
            # A plan the person sent is at fault when it misses the canal or the samples' sections.
            p_first, p_last = _span(p_crossed, "plan", path, float(np.median(np.diff(canal.arclength))))
            overlap = np.flatnonzero(crossed & p_crossed)
            if overlap.size == 0 or overlap[-1] - overlap[0] + 1 < MIN_SPAN_SECTIONS:
                raise InvalidInputError(
                    f"expected a plan over the sections the samples cross ({first}..{last}, at least "
                    f"{MIN_SPAN_SECTIONS} of them), got one over sections {p_first}..{p_last}", field="plan")
        both = crossed & p_crossed
        first, last = _span(both, "samples")
        pushed = _filled(crossed, coords, first, last)
        planned = _filled(p_crossed, p_coords, first, last)
        shift, scale, d, cut = exclude_geometry(canal, pushed, planned, first)
        if not cut.any():
            raise InvalidInputError(
                "expected an exclude correction whose samples were pushed away from the canal's own path "
                f"(by at least {PUSH_THRESHOLD:.0%} of a section's radius) inside the canal, got none",
                field="samples",
            )
        # The span is where the push cut the canal.
        hit = np.flatnonzero(cut)
        a, b = int(hit[0]), int(hit[-1])
        shift, scale, d, cut, pushed = shift[a : b + 1], scale[a : b + 1], d[a : b + 1], cut[a : b + 1], pushed[a : b + 1]
        first, last = first + a, first + b
        moved, lo, hi = locally_moved(canal, first, last, shift, scale, blend)
        index = np.arange(first, last + 1)
        basis = canal.basis[index]
        cut_points = canal.directrix[index] + np.einsum("sk,skd->sd", pushed, basis)
        cut_dirs = np.einsum("sk,skd->sd", d, basis)
        cut_points[~cut] = np.nan
        cut_dirs[~cut] = np.nan
        applied = AppliedCorrection(correction, first, last, lo, hi, cut_points, cut_dirs, parent_rows(
            canal, max(lo - 1, 0), min(hi + 1, canal.n_sections - 1)))
    return replace(moved, parent=canal_digest(canal), corrections=(*canal.corrections, applied))


def reapplied_canal(base: Canal, corrections: list[Correction]) -> Canal:
    """``base`` refined by each correction in turn (a refit or an undo re-applies the rest)."""
    canal = base
    for correction in corrections:
        canal = corrected_canal(canal, correction)
    return canal


def canal_digest(canal: Canal) -> str:
    """A short content hash of a canal's model (the parent a refined canal names).

    Over the arrays' bytes, not the JSON: a model read back by ``from_dict`` has the same
    float64 values and so the same digest, and hashing 1,000 sections takes microseconds.
    """
    h = hashlib.sha256()
    arrays = [canal.directrix, canal.tangents, canal.normals, canal.arclength,
              canal.section_points, canal.end_depths]
    if canal.binormals is not None:
        arrays.append(canal.binormals)
    arrays += [canal.sections.params[k] for k in sorted(canal.sections.params)]
    for a in arrays:
        h.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
    h.update(json.dumps([canal.sections.kind, canal.options.to_dict(), canal.parent,
                         len(canal.corrections)], sort_keys=True).encode())
    return h.hexdigest()[:16]


def excluded_points(canal: Canal, points: FloatArray, inside: BoolArray | None = None) -> BoolArray:
    """Whether each point (M, D) lies where an exclude correction removed the canal: inside the
    parent's sections over the correction's changed range and outside the corrected canal.

    ``inside``: the points' containment in ``canal`` when the caller has it.
    """
    out = np.zeros(points.shape[0], dtype=bool)
    for applied in canal.corrections:
        rows = applied.before
        if rows is None or applied.correction.kind != "exclude":
            continue
        sections = CrossSections(canal.sections.kind, rows["sections"])
        loc = located_points(points, rows["directrix"], rows["tangents"], rows["basis"], sections)
        out |= (loc.axial == 0.0) & (loc.eta <= 1.0 + 1e-9)
    if out.any():
        held = canal.contains(points) if inside is None else inside
        out &= ~held
    return out


def exempt_crossings(canal: Canal) -> BoolArray:
    """Which demo crossings (N, n) lie on an excluded side (outside by the person's choice)."""
    n, m = canal.section_points.shape[:2]
    world = canal.directrix[:, None, :] + np.einsum("snk,skd->snd", canal.section_points, canal.basis)
    return excluded_points(canal, world.reshape(n * m, -1)).reshape(n, m)


def blend_dropped_crossings(parent: Canal, refined: Canal) -> BoolArray:
    """Which demo crossings (N, n) in the blend of ``refined``'s latest correction (its changed
    range outside its span) its parent held and ``refined`` does not: what an exclude's blend
    narrows away on the way into its span (none for an include, which only grows sections).
    :func:`excluded_points` marks them excluded.

    Each crossing is measured in its own section first (O(N n)); only those its corrected
    section leaves out are located in the whole corrected canal, a block at a time.
    """
    applied = refined.corrections[-1]
    out = np.zeros(refined.section_points.shape[:2], dtype=bool)
    rows = np.r_[applied.lo : applied.first, applied.last + 1 : applied.hi + 1]
    if rows.size == 0:
        return out
    out[rows] = _section_holds(parent, rows) & ~_section_holds(refined, rows)
    # The blend of the neighbouring planes may still hold a crossing its own section leaves out.
    where = np.argwhere(out)
    world = parent.directrix[where[:, 0]] + np.einsum(
        "ck,ckd->cd", parent.section_points[where[:, 0], where[:, 1]], parent.basis[where[:, 0]])
    block = max(1, LOCATE_BLOCK // refined.n_sections)
    for lo in range(0, world.shape[0], block):
        held = refined.contains(world[lo : lo + block])
        out[where[lo : lo + block][held, 0], where[lo : lo + block][held, 1]] = False
    return out


def _section_holds(canal: Canal, rows: IntArray) -> BoolArray:
    """Whether section i holds its demo crossings (rows (R,) -> (R, n)), as :meth:`Canal.contains` would."""
    coords = canal.section_points[rows]
    r, m = coords.shape[:2]
    norm, unit = unit_directions(coords.reshape(r * m, -1))
    reach = boundary_distance(canal.sections, np.repeat(rows, m), unit)
    return np.asarray(norm <= reach * (1.0 + CONTAINS_TOLERANCE)).reshape(r, m)


def correction_from_dict(data: dict[str, Any], dim: int) -> Correction:
    """A checked :class:`Correction` from its JSON form (the REST body, a stored row)."""
    return checked_correction(
        data.get("kind"), data.get("samples"), dim, data.get("weight", 1.0), data.get("label", ""),
        data.get("timestamps"), data.get("orientations"), data.get("plan"),
    )


__all__ = [
    "BLEND_FRACTION",
    "CORRECTION_KINDS",
    "INCLUDE_MARGIN",
    "LONGEST_BLEND_FACTOR",
    "MAX_CORRECTION_SAMPLES",
    "MIN_BLEND",
    "MIN_CORRECTION_SAMPLES",
    "MIN_SPAN_SECTIONS",
    "MIN_WIDTH_FRACTION",
    "PUSH_THRESHOLD",
    "REACH",
    "AppliedCorrection",
    "Correction",
    "CorrectionKind",
    "blend_dropped_crossings",
    "blend_width",
    "canal_digest",
    "checked_correction",
    "corrected_canal",
    "correction_from_dict",
    "exclude_geometry",
    "excluded_points",
    "exempt_crossings",
    "locally_moved",
    "longest_blend",
    "moved_frames",
    "path_crossings",
    "planned_coords",
    "reapplied_canal",
]
