"""The canal model: :func:`canal_core.fit.fit` builds it (Alg. 1 lines 1-6), :class:`Canal`
uses it.

``Canal`` is a frozen dataclass of arrays plus thin methods that call the pure functions of
the other modules (:func:`canal_core.reproduction.reproduce` for a reproduction); it
round-trips exactly through :meth:`Canal.to_dict` / :meth:`Canal.from_dict`
(:mod:`canal_core.io`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np

from . import reproduction
from .bounds import canal_extent, check_reach
from .clocks import Clock
from .corrections import (
    AppliedCorrection,
    canal_digest,
    checked_correction,
    corrected_canal,
    excluded_points,
    exempt_crossings,
)
from .cross_sections import CrossSections, section_radii
from .errors import InvalidInputError
from .frames import canal_frames
from .goal import goal_displacements
from .io import canal_dict, canal_fields
from .obstacles import demonstrated_largest_step, demonstrated_steps
from .options import FitOptions
from .orientation import OrientationModel
from .reproduce import (
    CONTAINS_TOLERANCE,
    END_DECAY,
    Location,
    located_inside,
    located_points,
    section_basis,
)
from .reproduction import Reproduction
from .surface import Mesh, envelope_vertices, ring_vertices, strip_mesh, tube_mesh
from .tracker import Tracker, TrackerGeometry, tracker_geometry
from .tube import in_plane_curvature
from .validation import BoolArray, FloatArray, check_int, check_point, check_points


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
    section_pace : array, shape (N,), or None
        Without time stamps, from a steady logger: the mean share of their samples the
        demonstrations had logged at each section, 0 to 1 (P1 of :mod:`canal_core.timing`);
        a reproduction asked for a duration is timed by it. None otherwise.
    envelope_margin : float
        The fit's report of how much the sections fitted to the plane crossings had to grow
        so that every demonstrated sample is inside: the largest relative enlargement of
        any section (0.02 = 2 %). See :func:`canal_core.enclosing.enclosing_scales`.
    parent : str or None
        The digest (:func:`canal_core.corrections.canal_digest`) of the canal this one was
        refined from by a correction; None for a canal fitted from demonstrations.
    corrections : tuple of AppliedCorrection
        Every correction applied since the fit, in order, with the sections each changed.
    clock : {"time", "index", "arc", "time+arc", "index+arc"}
        What the demonstrations were aligned by: their time stamps, their sample index (a
        steady logger without stamps), arc length, or a blend (:mod:`canal_core.clocks`).
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
    section_pace: FloatArray | None = None
    envelope_margin: float = 0.0
    #: The content digest of the canal this one was refined from (None for a fit).
    parent: str | None = None
    #: Every correction applied since the fit, in order (:mod:`canal_core.corrections`).
    corrections: tuple[AppliedCorrection, ...] = ()
    clock: Clock = "arc"

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
    def curvature(self) -> FloatArray:
        """The directrix's curvature vector in each section's in-plane coordinates, shape
        (N, D - 1) (b_k of :mod:`canal_core.tube`, F1)."""
        return in_plane_curvature(self.tangents, self.basis, self.arclength)

    @cached_property
    def radii(self) -> FloatArray:
        """Largest boundary distance from the directrix per section, shape (N,)."""
        return section_radii(self.sections)

    @cached_property
    def extent(self) -> tuple[FloatArray, float]:
        """(centre (D,), size) of the canal: the box around its directrix widened by its
        largest radius, and that box's diagonal (:func:`canal_core.bounds.canal_extent`).
        Starts and goals are held within :data:`canal_core.bounds.MAX_REACH` sizes of it."""
        return canal_extent(self.directrix, self.radii)

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
        return located_inside(self.locate(points), self.end_depths, self.radii, tol)

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
            Exclude only: the path the robot was on before the push (the canal's own
            reproduction from the first sample when None).

        Raises
        ------
        InvalidInputError
            ``samples`` malformed, too short or outside every section; ``plan`` sent with an
            include, or outside every section or off the samples' sections; ``kind`` unknown
            or an exclude that would close the canal.
        """
        correction = checked_correction(kind, samples, self.dim, weight, label, timestamps,
                                        orientations, plan)
        return corrected_canal(self, correction)


    def reproduce_detailed(
        self,
        start: Any,
        outside: str = "project",
        start_orientation: Any = None,
        goal: Any = None,
        duration: Any = None,
        *,
        entry: float | None = None,
        end_decay: float = END_DECAY,
        persistence: str = "learned",
        obstacles: Any = None,
        deadline: float | None = None,
    ) -> Reproduction:
        """Reproduce from ``start`` (D,) by the ratio rule (Alg. 1 lines 7-15): see
        :func:`canal_core.reproduction.reproduce`.

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
            Seconds; the times are stretched to end there (without time stamps, paced by
            ``section_pace`` when the logger was steady, else at constant speed along the path).
        entry : float or None
            None (default): a start outside enters the canal over the length in which the
            demonstrations' own start offsets half faded (:mod:`canal_core.entry`); a
            fraction of the canal's length: the entry blend over that length.
        end_decay : float
            Fraction of the canal's length (``entry=0, end_decay=0`` with
            ``persistence="constant"``: the paper's constant, clamped ratio).
        persistence : {"learned", "constant", "learned+end"}
            How much of the start's ratio is kept along the canal before the end decay:
            what the demonstrations themselves kept of their start offsets, section by
            section (:func:`canal_core.reproduce.learned_persistence`, shrunk towards the
            paper's constant ratio by one pseudo-demonstration), or all of it (the paper).
            "learned+end": for a start inside and no goal, kept up to the demonstrations'
            ends, shrunk towards the end decay instead of faded by it (the reproduction
            then ends where their regression on the start puts it).
        obstacles : Scene or list of obstacle dicts, optional
            What stands in the canal (:mod:`canal_core.obstacles`): the path detours through
            the free part of each section, or stops short saying ``blocked``.
        deadline : float, optional
            ``time.monotonic()`` by which a detour around ``obstacles`` must be found, else
            :class:`~canal_core.errors.TooSlowError`.
        """
        return reproduction.reproduce(self, start, outside, start_orientation, goal, duration,
                                      entry=entry, end_decay=end_decay, persistence=persistence,
                                      obstacles=obstacles, deadline=deadline)

    @cached_property
    def largest_step(self) -> float:
        """The longest step a demonstration takes from one section to the next (or the
        directrix, when longer): no detour around obstacles steps further."""
        return demonstrated_largest_step(self.directrix, self.basis, self.section_points)

    @cached_property
    def section_steps(self) -> FloatArray:
        """The largest step a demonstration takes into or out of each section, shape (N,):
        the pace a live detour keeps around each section (:mod:`canal_core.tracker_obstacles`)."""
        return demonstrated_steps(self.directrix, self.basis, self.section_points)

    def with_goal(self, goal: Any) -> Canal:
        """This canal deformed so that its directrix ends at ``goal`` (D,) (:mod:`canal_core.goal`).

        The start region is untouched; frames are recomputed on the displaced directrix and
        every section keeps its shape in its new plane (and its orientation, when learned).
        """
        target = check_reach(check_point(goal, self.dim, "goal"), *self.extent, "goal")
        centres = self.directrix + goal_displacements(self.arclength, target - self.directrix[-1])
        steps = np.linalg.norm(np.diff(centres, axis=0), axis=1)
        # A canal of two sections bent to end where it starts shrinks to a point: no
        # tangent, no sections' planes, nothing a robot could follow.
        if not float(steps.sum()) > 1e-9 * max(float(self.arclength[-1]), 1e-300):
            raise InvalidInputError(
                f"expected a goal the canal can be bent to end at, got {target.tolist()}, where "
                "it starts: the canal would shrink to a point; give a goal "
                "away from the start, or fit more samples", field="goal")
        tangents, normals, binormals = canal_frames(centres, self.options)
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
            section_pace=self.section_pace,
            envelope_margin=self.envelope_margin,
            clock=self.clock,
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
        """A JSON-able dict (format ``canal-model`` version 1, :mod:`canal_core.io`) that
        round-trips exactly."""
        return canal_dict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Canal:
        """Rebuild a canal written by :meth:`to_dict`; raises :class:`ModelFormatError`."""
        return cls(**canal_fields(data))
