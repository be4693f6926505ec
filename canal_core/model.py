"""The canal model: :func:`fit` builds it (Alg. 1 lines 1-6), :class:`Canal` uses it.

``Canal`` is a frozen dataclass of arrays plus thin methods that call the pure functions of
the other modules; it round-trips exactly through :meth:`Canal.to_dict` / :meth:`Canal.from_dict`
(JSON-able: floats are written with ``repr`` precision, so every float64 survives).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from functools import cached_property
from typing import Any, Literal, cast, get_args

import numpy as np

from .alignment import (
    dtw_aligned_demonstrations,
    dtw_parameters,
    resampled_demonstrations,
    spline_parameter,
)
from .corrections import (
    AppliedCorrection,
    canal_digest,
    checked_correction,
    corrected_canal,
    excluded_points,
    exempt_crossings,
)
from .cross_sections import (
    KINDS_3D,
    CrossSections,
    fitted_sections,
    floored_sections,
    scaled_sections,
    section_kind,
    section_kinds,
    section_radii,
)
from .crossings import in_plane_coordinates, located_crossings, sections_of_samples
from .directrix import directrix_gmr, directrix_mean
from .envelope import enclosing_scales
from .errors import DegenerateCanalError, InvalidInputError, ModelFormatError, OutsideCanalError
from .frames import frenet_frames, planar_frames, rotation_minimizing_frames, smoothed_curve
from .goal import goal_displacements
from .orientation import OrientationModel, fitted_orientations
from .preprocess import STILL_TOLERANCE, PreparedDemonstration, prepared_samples_many
from .reproduce import (
    END_DECAY,
    ENTRY_FRACTION,
    PERSISTENCE_PRIOR_WEIGHT,
    PERSISTENCES,
    Location,
    learned_persistence,
    located_points,
    path_ratios,
    ratio_rule_positions,
    reach_along,
    section_basis,
    start_and_located_points,
)
from .surface import Mesh, envelope_vertices, ring_vertices, strip_mesh, tube_mesh
from .timing import (
    arc_length_times,
    finite_velocities,
    reproduction_times,
    rescaled_times,
    section_times,
)
from .tracker import Tracker, TrackerGeometry, tracker_geometry
from .validation import (
    BoolArray,
    FloatArray,
    check_choice,
    check_demonstration_orientations,
    check_demonstrations,
    check_fraction,
    check_int,
    check_point,
    check_points,
    check_positive,
    check_quaternion,
)

FORMAT = "canal-model"
FORMAT_VERSION = 1

#: Frame kinds, alignments and directrices: each ``Literal`` is the one list of names; the
#: tuples are derived from it, and canal_protocol derives the HTTP contract from both.
FrameKind = Literal["rmf", "frenet"]
AlignmentKind = Literal["spline", "dtw"]
DirectrixKind = Literal["mean", "gmr"]
#: The built-in choices of ``cross_section`` ("interval" is the 2-D form of each and is not
#: chosen by name); kinds registered later are accepted by :func:`fit` too
#: (:func:`canal_core.sections.section_kinds` with dim=3 lists them all).
CROSS_SECTIONS: tuple[str, ...] = KINDS_3D
FRAMES: tuple[FrameKind, ...] = get_args(FrameKind)
ALIGNMENTS: tuple[AlignmentKind, ...] = get_args(AlignmentKind)
DIRECTRICES: tuple[DirectrixKind, ...] = get_args(DirectrixKind)
#: What a reproduction does with a start outside the canal (:meth:`Canal.reproduce_detailed`).
OutsideRule = Literal["project", "raise"]
OUTSIDE_RULES: tuple[OutsideRule, ...] = get_args(OutsideRule)
#: Bounds of ``n_samples`` (N, the number of cross-sections) and of ``frame_smoothing``; the
#: service's limits are these. A fit's cost grows faster than N (5 demos of 1,000 points:
#: about 1 s at N = 5,000, 38 s at 20,000, over 7 min at 100,000, on a busy 2-core machine),
#: so N stops where a fit still answers within an HTTP request's patience.
MIN_SAMPLES = 2
MAX_SAMPLES = 5_000
MAX_FRAME_SMOOTHING = 0.25
#: Relative tolerance of :meth:`Canal.contains` on eta and on the axial offset at the ends.
CONTAINS_TOLERANCE = 1e-6


@dataclass(frozen=True)
class FitOptions:
    """How a canal was fitted (see :func:`fit`)."""

    #: One of :data:`CROSS_SECTIONS`.
    cross_section: str = "circle"
    frames: FrameKind = "rmf"
    alignment: AlignmentKind = "spline"
    directrix: DirectrixKind = "mean"
    #: In [MIN_SAMPLES, MAX_SAMPLES].
    n_samples: int = 200
    #: Gaussian smoothing of the curve the frames are computed on, as a fraction of
    #: n_samples (0 = frames of the raw directrix, as in the paper). See canal_core.frames.
    frame_smoothing: float = 0.02

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True, eq=False)
class Reproduction:
    """A trajectory reproduced by the ratio rule.

    Attributes
    ----------
    positions : array, shape (N', D)
        The start, then one point per remaining cross-section, ending on the last one.
    start : array, shape (D,)
    inside : bool
        Whether the start lies inside the canal.
    eta : float
        Ratio the trajectory follows after the start (the start's, at most 1); it fades to 0
        into the last sections (see :func:`canal_core.reproduce.path_ratios`).
    section_index : int
        Section the start was located at.
    projected : bool
        True when the start's ratio exceeded 1: the path enters the canal over the entry
        blend and then follows the boundary's ratio 1.
    times : array, shape (N',), or None
        Seconds from the start, following the demonstrations' mean speed profile (None
        when they carried no time stamps and no duration was asked for).
    velocities : array, shape (N', D), or None
        Finite differences of ``positions`` over ``times`` (zero at the end).
    orientations : array, shape (N', 4), or None
        One unit quaternion [qx, qy, qz, qw] per position when the canal learned orientation
        (see :mod:`canal_core.orientation`): the start orientation (or its section's mean),
        then the rotational ratio rule. Hemisphere-continuous.
    orientation_eta : float or None
        The start orientation's angle from its section mean over the section's spread,
        before clamping to 1 (None without a start orientation or orientation model).
    goal : array, shape (D,), or None
        The goal the canal was deformed to, when one was given.
    """

    positions: FloatArray
    start: FloatArray
    inside: bool
    eta: float
    section_index: int
    projected: bool
    times: FloatArray | None = None
    velocities: FloatArray | None = None
    orientations: FloatArray | None = None
    orientation_eta: float | None = None
    goal: FloatArray | None = None


@dataclass(frozen=True, eq=False)
class Canal:
    """A fitted canal surface.

    Attributes
    ----------
    directrix : array, shape (N, D)
    tangents, normals : arrays, shape (N, D)
    binormals : array, shape (N, 3), or None in 2-D
    arclength : array, shape (N,)
    sections : CrossSections
    section_points : array, shape (N, n, D - 1)
        In-plane coordinates of where each demonstration crosses each section plane.
    end_depths : array, shape (2,)
        How far the demonstrations reach behind the first plane and past the last one.
        Demonstrations rarely start exactly in the first cross-section plane (it is tilted
        by the mean's tangent); the canal's end sections are extruded along t by these
        depths so that every demonstrated point is inside the canal.
    options : FitOptions
    orientation : OrientationModel or None
        Per-section mean orientation and spread, when every demonstration had orientations.
    section_times : array, shape (N,), or None
        Mean time (s) at which the demonstrations reach each section, from the first
        (:mod:`canal_core.timing`); None when they carried no time stamps.
    envelope_margin : float
        The fit's report of how much the sections fitted to the plane crossings had to grow
        so that every demonstrated sample is inside: the largest relative enlargement of
        any section (0.02 = 2 %). See :func:`canal_core.envelope.enclosing_scales`.
    parent : str or None
        The digest (:func:`canal_core.corrections.canal_digest`) of the canal this one was
        refined from by a correction; None for a canal fitted from demonstrations.
    corrections : tuple of AppliedCorrection
        Every correction applied since the fit, in order, with the sections each changed.
    """

    directrix: FloatArray
    tangents: FloatArray
    normals: FloatArray
    binormals: FloatArray | None
    arclength: FloatArray
    sections: CrossSections
    section_points: FloatArray
    end_depths: FloatArray = field(default_factory=lambda: np.zeros(2))
    options: FitOptions = field(default_factory=FitOptions)
    orientation: OrientationModel | None = None
    section_times: FloatArray | None = None
    envelope_margin: float = 0.0
    #: The content digest of the canal this one was refined from (None for a fit).
    parent: str | None = None
    #: Every correction applied since the fit, in order (:mod:`canal_core.corrections`).
    corrections: tuple[AppliedCorrection, ...] = ()

    # -- one-line summaries (the dataclass repr would print every array) ---------------
    def _summary_numbers(self) -> tuple[float, float, float]:
        length = float(self.arclength[-1] - self.arclength[0]) if self.arclength.size else 0.0
        radii = self.radii
        return length, float(radii.min()), float(radii.max())

    def __repr__(self) -> str:
        length, r_min, r_max = self._summary_numbers()
        return (f"Canal(dim={self.dim}, sections={self.n_sections}, kind={self.section_kind!r}, "
                f"demos={self.n_demos}, length={length:.4g}, radius={r_min:.4g}..{r_max:.4g})")

    def __str__(self) -> str:
        length, r_min, r_max = self._summary_numbers()
        return (f"{self.dim}-D canal: {self.n_sections} {self.section_kind} sections from "
                f"{self.n_demos} demos, length {length:.4g}, radius {r_min:.4g} to {r_max:.4g}")

    # -- derived ---------------------------------------------------------------------
    @property
    def dim(self) -> int:
        return int(self.directrix.shape[1])

    @property
    def n_sections(self) -> int:
        return int(self.directrix.shape[0])

    @property
    def n_demos(self) -> int:
        return int(self.section_points.shape[1])

    @property
    def has_orientation(self) -> bool:
        return self.orientation is not None

    @property
    def section_kind(self) -> str:
        return self.sections.kind

    @cached_property
    def basis(self) -> FloatArray:
        """In-plane unit vectors per section, shape (N, D - 1, D)."""
        return section_basis(self.normals, self.binormals)

    @cached_property
    def plane_offsets(self) -> FloatArray:
        """t_i . c_i per section, shape (N,): plane i is {x : t_i . x = t_i . c_i}."""
        return np.asarray(np.einsum("nd,nd->n", self.directrix, self.tangents), dtype=np.float64)

    @cached_property
    def radii(self) -> FloatArray:
        """Largest boundary distance from the directrix per section, shape (N,)."""
        return section_radii(self.sections)

    @cached_property
    def bounds(self) -> FloatArray:
        """Axis-aligned bounding box of the canal, shape (2, D): min corner, max corner."""
        if self.dim == 2:
            s = self.sections.params
            pts = np.vstack(
                [self.directrix + s["lower"][:, None] * self.normals, self.directrix + s["upper"][:, None] * self.normals]
            )
        else:
            pts = ring_vertices(self.directrix, self.basis, self.sections, 32).reshape(-1, 3)
        return np.stack([pts.min(axis=0), pts.max(axis=0)])

    # -- queries ---------------------------------------------------------------------
    def locate(self, points: Any) -> Location:
        """Where points (M, D) sit in the canal (see :func:`canal_core.reproduce.located_points`)."""
        pts = check_points(points, self.dim)
        return located_points(pts, self.directrix, self.tangents, self.basis, self.sections, self.end_depths)

    def contains(self, points: Any, tol: float = CONTAINS_TOLERANCE) -> BoolArray:
        """Whether each point (M, D) lies in the volume swept by the cross-sections.

        ``tol`` is relative: eta <= 1 + tol, and at the two ends an axial offset up to
        tol times the largest radius.
        """
        return self._inside(self.locate(points), tol)

    def excluded(self, points: Any) -> BoolArray:
        """Whether each point (M, D) lies on a side a person excluded (see
        :mod:`canal_core.corrections`): demonstrated samples there are outside the canal by
        that person's choice, and exempt from the all-samples-inside rule."""
        return excluded_points(self, check_points(points, self.dim))

    @cached_property
    def exempt_crossings(self) -> BoolArray:
        """Which demo crossings ``section_points`` (N, n) lie on an excluded side."""
        return exempt_crossings(self)

    @property
    def digest(self) -> str:
        """A content hash of the model (what a refined canal names as its ``parent``)."""
        return canal_digest(self)

    def corrected(
        self,
        kind: str,
        samples: Any,
        weight: Any = 1.0,
        label: str = "",
        *,
        timestamps: Any = None,
        orientations: Any = None,
        plan: Any = None,
    ) -> Canal:
        """A new canal refined by a person's correction (:mod:`canal_core.corrections`).

        Parameters
        ----------
        kind : {"include", "exclude"}
        samples : array_like, shape (M, D)
            The corrected path over part of the canal, M >= 4.
        weight : float
            How much an include counts against one demonstration.
        plan : array_like, shape (P, D), optional
            Exclude: the path the robot was on before the push (the canal's own
            reproduction from the first sample when None).

        Raises
        ------
        InvalidInputError
            ``samples`` malformed, too short or outside every section; ``kind`` unknown or
            an exclude that would close the canal.
        """
        correction = checked_correction(kind, samples, self.dim, weight, label, timestamps, orientations)
        path = None if plan is None else check_points(plan, self.dim, "plan")
        return corrected_canal(self, correction, path)

    def _inside(self, loc: Location, tol: float) -> BoolArray:
        axial_tol = tol * float(self.radii.max(initial=0.0))
        reach = np.where(loc.axial < 0.0, self.end_depths[0], self.end_depths[1]) + axial_tol
        return np.asarray((loc.eta <= 1.0 + tol) & (np.abs(loc.axial) <= reach))

    def reproduce_detailed(
        self,
        start: Any,
        outside: str = "project",
        start_orientation: Any = None,
        goal: Any = None,
        duration: Any = None,
        *,
        entry: float = ENTRY_FRACTION,
        end_decay: float = END_DECAY,
        persistence: str = "learned",
    ) -> Reproduction:
        """Reproduce from ``start`` (D,) by the ratio rule (Alg. 1 lines 7-15).

        The start is located on the earliest section that holds it
        (:func:`canal_core.reproduce.start_locations`); its ratio eta is carried along the
        canal on the schedule of :func:`canal_core.reproduce.path_ratios` (entry blend for a
        start outside, end decay onto the demonstrations' end).

        Parameters
        ----------
        start : array_like, shape (D,)
        outside : {"project", "raise"}
            For a start outside the canal: enter the canal over the entry blend and say so
            in ``projected``, or raise :class:`OutsideCanalError`.
        start_orientation : array_like, shape (4,), optional
            Unit quaternion [qx, qy, qz, qw] of the start pose. Its offset from the start
            section's mean orientation is carried by the rotational ratio rule
            (:mod:`canal_core.orientation`). Checked always, used only when the canal has an
            orientation model; without it the orientations are the section means.
        goal : array_like, shape (D,), optional
            End the reproduction here: the canal is deformed first (:meth:`with_goal`).
        duration : float, optional
            Seconds; the times are stretched to end there (constant speed along the path
            when the model has no speed profile).
        entry, end_decay : float
            Fractions of the canal's length (0 and 0 with ``persistence="constant"``: the
            paper's constant, clamped ratio).
        persistence : {"learned", "constant"}
            How much of the start's ratio is kept along the canal before the end decay:
            what the demonstrations themselves kept of their start offsets, section by
            section (:func:`canal_core.reproduce.learned_persistence`, shrunk towards the
            paper's constant ratio by one pseudo-demonstration), or all of it (the paper).
        """
        point = check_point(start, self.dim, "start")
        check_choice(outside, OUTSIDE_RULES, "outside")
        quat = None if start_orientation is None else check_quaternion(start_orientation)
        entry = check_fraction(entry, "entry", maximum=1.0)
        end_decay = check_fraction(end_decay, "end_decay", maximum=1.0)
        check_choice(persistence, PERSISTENCES, "persistence")
        seconds = None if duration is None else check_positive(duration, "duration")
        target = None if goal is None else check_point(goal, self.dim, "goal")
        canal = self if target is None else self.with_goal(target)
        loc, held = start_and_located_points(
            point[None, :], canal.directrix, canal.tangents, canal.basis, canal.sections, canal.plane_offsets
        )
        eta = float(loc.eta[0])
        index, alpha = int(loc.index[0]), float(loc.alpha[0])
        inside = bool(canal._inside(held, CONTAINS_TOLERANCE)[0])
        if outside == "raise" and not inside:
            raise OutsideCanalError(
                f"expected start inside the canal, got eta={eta:.4g} at section {index}"
                + (f" and {float(loc.axial[0]):.4g} beyond its end plane" if loc.axial[0] else ""),
                field="start",
            )
        first = min(index + 1, canal.n_sections - 1)
        s0 = float(canal.arclength[index] + alpha * (canal.arclength[first] - canal.arclength[index]))
        u = loc.direction[0]
        reach = reach_along(canal.sections, index, canal.n_sections, u)  # sections index .. N-1
        share: FloatArray | None = None
        if persistence == "learned":
            kept = learned_persistence(
                canal.section_points[index:], reach, u, alpha, prior=1.0, weight=PERSISTENCE_PRIOR_WEIGHT
            )
            if kept is not None:
                # At most the start's own ratio: an inside start stays inside by construction.
                share = np.clip(kept[first - index - 1 :], 0.0, 1.0)
        ratios = path_ratios(eta, canal.arclength[first:], s0, entry, end_decay, share)
        path = ratio_rule_positions(first, ratios, u, canal.directrix, canal.basis, canal.sections, reach[first - index :])
        positions = np.vstack([point, path])
        times = None
        if canal.section_times is not None:
            times = reproduction_times(canal.section_times, index, alpha, positions.shape[0])
            if seconds is not None:
                times = rescaled_times(times, seconds)
        elif seconds is not None:
            times = arc_length_times(positions, seconds)
        orientations, orientation_eta = None, None
        if canal.orientation is not None:
            orientations, orientation_eta = canal.orientation.reproduced(index, first, quat)
        return Reproduction(
            positions=positions,
            start=point,
            inside=inside,
            eta=min(eta, 1.0),
            section_index=index,
            projected=eta > 1.0,
            times=times,
            velocities=None if times is None else finite_velocities(positions, times),
            orientations=orientations,
            orientation_eta=orientation_eta,
            goal=target,
        )

    def with_goal(self, goal: Any) -> Canal:
        """This canal deformed so that its directrix ends at ``goal`` (D,) (:mod:`canal_core.goal`).

        The start region is untouched; frames are recomputed on the displaced directrix and
        every section keeps its shape in its new plane (and its orientation, when learned).
        """
        target = check_point(goal, self.dim, "goal")
        centres = self.directrix + goal_displacements(self.arclength, target - self.directrix[-1])
        tangents, normals, binormals = canal_frames(centres, self.options)
        steps = np.linalg.norm(np.diff(centres, axis=0), axis=1)
        return Canal(
            directrix=centres,
            tangents=tangents,
            normals=normals,
            binormals=binormals,
            arclength=np.concatenate([[0.0], np.cumsum(steps)]),
            sections=self.sections,
            section_points=self.section_points,
            end_depths=self.end_depths,
            options=self.options,
            orientation=self.orientation,
            section_times=self.section_times,
            envelope_margin=self.envelope_margin,
        )

    def reproduce(self, start: Any) -> FloatArray:
        """Trajectory (N', D) from ``start`` (D,) to the canal's end; see :meth:`reproduce_detailed`."""
        return self.reproduce_detailed(start).positions

    def tracker_geometry(self) -> TrackerGeometry:
        """What every live stream of this canal shares: planes, sections, and the learned
        orientations and section times that make targets carry an orientation and a
        feed-forward velocity (see :mod:`canal_core.tracker`)."""
        return tracker_geometry(
            self.directrix, self.tangents, self.basis, self.sections,
            orientations=None if self.orientation is None else self.orientation.means,
            section_times=self.section_times,
        )

    def tracker(self, lookahead: int = 1) -> Tracker:
        """A reactive tracker for one live stream (see :mod:`canal_core.tracker`)."""
        check_int(lookahead, 1, "lookahead")
        return Tracker(self.tracker_geometry(), lookahead)

    def mesh(self, n_angles: int = 32, caps: bool = False, envelope: bool = False) -> Mesh:
        """The canal surface as a triangle mesh.

        Parameters
        ----------
        n_angles : int
            Vertices per ring (3-D).
        caps : bool
            Close both ends with a fan to the end directrix points (3-D).
        envelope : bool
            Use the true envelope of Eq. 9 (``circle`` sections only) instead of the ring form.
        """
        if self.dim == 2:
            return strip_mesh(self.directrix, self.normals, self.sections)
        check_int(n_angles, 3, "n_angles")
        if envelope:
            if not self.sections.spec.isotropic:
                raise InvalidInputError(
                    "expected envelope=True only with isotropic (circle) sections, "
                    f"got {self.sections.kind!r}",
                    field="envelope",
                )
            rings = envelope_vertices(
                self.directrix, self.tangents, self.basis, self.sections.params["radius"],
                self.arclength, n_angles,
            )
        else:
            rings = ring_vertices(self.directrix, self.basis, self.sections, n_angles)
        return tube_mesh(rings, self.directrix, caps)

    # -- serialisation ---------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """A JSON-able dict (format ``canal-model`` version 1) that round-trips exactly."""
        return {
            "format": FORMAT,
            "version": FORMAT_VERSION,
            "dim": self.dim,
            "options": self.options.to_dict(),
            "directrix": self.directrix.tolist(),
            "tangents": self.tangents.tolist(),
            "normals": self.normals.tolist(),
            "binormals": None if self.binormals is None else self.binormals.tolist(),
            "arclength": self.arclength.tolist(),
            "sections": self.sections.to_dict(),
            "section_points": self.section_points.tolist(),
            "end_depths": self.end_depths.tolist(),
            # Absent in models saved before orientation existed; None when not learned.
            "orientation": None if self.orientation is None else self.orientation.to_dict(),
            # Optional keys (absent in models written before them; from_dict defaults them).
            "section_times": None if self.section_times is None else self.section_times.tolist(),
            "envelope_margin": self.envelope_margin,
            "parent": self.parent,
            "corrections": [c.to_dict() for c in self.corrections],
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Canal:
        """Rebuild a canal written by :meth:`to_dict`; raises :class:`ModelFormatError`."""
        try:
            if data.get("format") != FORMAT or data.get("version") != FORMAT_VERSION:
                raise ModelFormatError(
                    f"expected format {FORMAT!r} version {FORMAT_VERSION}, got "
                    f"{data.get('format')!r} version {data.get('version')!r}",
                    field="format",
                )
            arr = {
                k: np.asarray(data[k], dtype=np.float64)
                for k in ("directrix", "tangents", "normals", "arclength", "section_points", "end_depths")
            }
            dim = int(data["dim"])
            n = arr["directrix"].shape[0]
            sec = dict(data["sections"])
            kind = sec.pop("kind")
            if kind not in section_kinds(dim):
                raise ModelFormatError(
                    f"expected a {dim}-D cross-section kind among {', '.join(map(repr, section_kinds(dim)))}, "
                    f"got {kind!r}",
                    field="sections",
                )
            params = {k: np.asarray(v, dtype=np.float64) for k, v in sec.items()}
            expected_params = section_kind(kind).params
            if sorted(params) != sorted(expected_params):
                raise ModelFormatError(
                    f"expected {kind} section parameters {', '.join(expected_params)}, got {', '.join(params)}",
                    field="sections",
                )
            binormals = None if data["binormals"] is None else np.asarray(data["binormals"], dtype=np.float64)
            expected = {
                "directrix": (n, dim), "tangents": (n, dim), "normals": (n, dim), "arclength": (n,),
                "end_depths": (2,),
            }
            for key, shape in expected.items():
                if arr[key].shape != shape:
                    raise ModelFormatError(f"expected {key} of shape {shape}, got {arr[key].shape}", field=key)
            if any(v.shape[0] != n for v in params.values()):
                raise ModelFormatError(f"expected {n} cross-sections in every parameter", field="sections")
            raw_orientation = data.get("orientation")
            orientation = (
                None if raw_orientation is None else OrientationModel.from_dict(raw_orientation, n)
            )
            return cls(
                directrix=arr["directrix"],
                tangents=arr["tangents"],
                normals=arr["normals"],
                binormals=binormals,
                arclength=arr["arclength"],
                sections=CrossSections(kind, params),
                section_points=arr["section_points"],
                end_depths=arr["end_depths"],
                # Models saved before frame smoothing existed had frames of the raw directrix.
                options=FitOptions(**{"frame_smoothing": 0.0, **data["options"]}),
                orientation=orientation,
                section_times=_optional_times(data.get("section_times"), n),
                envelope_margin=float(data.get("envelope_margin", 0.0)),
                # Absent in models written before corrections existed.
                parent=None if data.get("parent") is None else str(data["parent"]),
                corrections=tuple(
                    AppliedCorrection.from_dict(c, n, dim) for c in data.get("corrections") or ()
                ),
            )
        except ModelFormatError:
            raise
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise ModelFormatError(f"malformed canal model: {exc!r}") from exc


# -------------------------------------------------------------------------------------


def _optional_times(values: Any, n: int) -> FloatArray | None:
    if values is None:
        return None
    times = np.asarray(values, dtype=np.float64)
    if times.shape != (n,) or not np.all(np.isfinite(times)) or np.any(np.diff(times) < 0.0):
        raise ModelFormatError(
            f"expected section_times of shape ({n},), finite and non-decreasing, got shape {times.shape}",
            field="section_times",
        )
    return times


def canal_frames(centres: FloatArray, options: FitOptions) -> tuple[FloatArray, FloatArray, FloatArray | None]:
    """Tangents, normals and binormals (None in 2-D) of a directrix (N, D), as ``options`` ask."""
    frame_curve = smoothed_curve(centres, options.frame_smoothing * options.n_samples)
    if centres.shape[1] == 2:
        tangents, normals = planar_frames(frame_curve)
        return tangents, normals, None
    if options.frames == "frenet":
        return frenet_frames(frame_curve)
    return rotation_minimizing_frames(frame_curve)


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


def fit_options(
    cross_section: str = "circle",
    frames: str = "rmf",
    alignment: str = "spline",
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


def fit(
    demos: Any,
    timestamps: Any = None,
    cross_section: str = "circle",
    frames: str = "rmf",
    alignment: str = "spline",
    directrix: str = "mean",
    n_samples: int = 200,
    still_tolerance: float = STILL_TOLERANCE,
    frame_smoothing: float = FitOptions.frame_smoothing,
    orientations: Any = None,
    by_time: bool | None = None,
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
        is False, its alignment (by time where given, else by arc length).
    cross_section : {"circle", "mec", "ellipse", "spline"}
    frames : {"rmf", "frenet"}
    alignment : {"spline", "dtw"}
    directrix : {"mean", "gmr"}
    n_samples : int
        N, the number of cross-sections.
    frame_smoothing : float
        Frames are computed on the directrix smoothed by a Gaussian of this fraction of N
        (0.02 by default; 0 = the paper's frames of the raw directrix). See
        :func:`canal_core.frames.smoothed_curve`.
    by_time : bool, optional
        Align by the time stamps (default when they are given) or, when False, by arc
        length while still keeping the speed profile.
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

    # Timestamps are prepared (repaired or refused) even when the alignment is by arc
    # length: they still give the speed profile.
    prepared = prepared_samples_many(
        demos_, times_, [f"demos[{j}]" for j in range(len(demos_))],
        [f"timestamps[{j}]" for j in range(len(demos_))], still_tolerance=still_tolerance,
    )
    positions = [p.positions for p in prepared]
    stamped = [p.timestamps for p in prepared]
    align_by_time = by_time is None or bool(by_time)
    times: list[FloatArray | None] = stamped if align_by_time else [None] * len(stamped)

    if options.alignment == "dtw":
        aligned = dtw_aligned_demonstrations(positions, times, options.n_samples)
    else:
        aligned = resampled_demonstrations(positions, times, options.n_samples)

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
    if not np.any(np.abs(coords) > 1e-12 * arclength[-1]):
        raise DegenerateCanalError(
            "every demonstration is identical: the canal has zero radius everywhere", field="demos"
        )
    size = float(np.abs(coords).max())
    sections = floored_sections(fitted_sections(coords, options.cross_section), 1e-9 * size)
    # Make the canal a true envelope of the demonstrated samples, not only of the crossings.
    # Every genuine sample counts, the trimmed still ends included (glitches do not); its
    # phase is its place in the prepared demonstration, 0 / 1 in the still ends.
    samples = np.vstack([np.take(d, p.sample_rows, axis=0) for d, p in zip(demos_, prepared, strict=True)])
    phase = np.concatenate([p.sample_phase for p in prepared])
    # Each sample starts its search at the sections its demo crosses there (not at its own
    # phase): demos ahead of or behind the mean are then found at once.
    approx = np.rint(np.concatenate([
        sections_of_samples(crossing_index, j, p.sample_phase * (options.n_samples - 1))
        for j, p in enumerate(prepared)
    ])).astype(np.int64)
    envelope = enclosing_scales(samples, approx, centres, tangents, basis, sections)
    sections = scaled_sections(sections, envelope.scale)
    orientation = None
    if quats_ is not None:
        orientation = _fitted_orientation(prepared, times, quats_, options)
    return Canal(
        end_depths=np.maximum(end_depths(samples, phase, centres, tangents), envelope.depths),
        section_times=section_times(positions, stamped, options.n_samples, align_by_time),
        envelope_margin=float(envelope.scale.max() - 1.0),
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


def _fitted_orientation(
    prepared: list[PreparedDemonstration],
    times: list[FloatArray | None],
    quaternions: list[FloatArray],
    options: FitOptions,
) -> OrientationModel:
    """The orientation model on the same alignment as the positions.

    Orientations follow the rows the preparation stage kept for their positions, at the
    spline parameter the positions were aligned by (``times``: the stamps, or None for arc
    length).
    """
    positions = [p.positions for p in prepared]
    parameters = [spline_parameter(d, t) for d, t in zip(positions, times, strict=True)]
    if options.alignment == "dtw":
        at = dtw_parameters(positions, times, options.n_samples)
    else:
        at = np.broadcast_to(np.linspace(0.0, 1.0, options.n_samples), (len(prepared), options.n_samples))
    return fitted_orientations([q[p.rows] for q, p in zip(quaternions, prepared, strict=True)], parameters, at)
