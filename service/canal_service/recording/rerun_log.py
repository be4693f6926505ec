"""The Rerun side of a skill's recording: one RecordingStream per segment, blueprint, CLI tools.

Entities and timelines::

    demos/<id>/path         LineStrips3D       wall_time
    demos/<id>/start        Points3D           wall_time   labelled "demo <id> <label>"
    demos/<id>/info         AnyValues          wall_time   demo_id, label, n_samples
    demos/<id>/position     Scalars            sample (+ demo_time when timestamps were given)
    demos/<id>              Clear(recursive)   wall_time   on removal
    model/v<k>/directrix    LineStrips3D       wall_time, model_version (model version k)
    model/v<k>/mesh         Mesh3D             wall_time, model_version (normals, radius colours)
    model/v<k>/rings        LineStrips3D       wall_time, model_version
    model/v<k>/info         AnyValues          wall_time, model_version
    model/v<k>/radius       BarChart           wall_time, model_version (radius per section index)
    model/v<k>/route_<r>/   directrix, mesh, rings, radius as above, and info (route r): a
                            model of several routes draws its routes and not the canal of all
    model/v<k-1>            Clear(recursive)   wall_time   when version k arrives
    corrections/v<k>/samples LineStrips3D      wall_time, model_version (the path of the
                            correction that made version k: green include, orange exclude)
    corrections/v<k>/before LineStrips3D       wall_time, model_version (the changed sections
                            in the parent canal), corrections/v<k>/after (in version k),
                            corrections/v<k>/info AnyValues (kind, label, weight, span)
    frames/v<k>             Arrows3D           wall_time, model_version (tangent r, normal g, binormal b)
    radius/v<version>       Scalars            section (the directrix parameter, 0..N-1);
                            radius/v<version>/route_<r> for a model of several routes
    reproductions/<n>/path  LineStrips3D       wall_time, model_version (n-th reproduction)
    reproductions/<n>/start Points3D           wall_time, model_version
    reproductions/<n>/orientation Arrows3D     wall_time (triads, when it has orientations)
    reproductions/<n>/point Points3D+Transform3D  reproduction_time (when it has times)
    reproductions/<n>/eta   Scalars            wall_time
    reproductions/<n>/inside Scalars (0/1)     wall_time
    ratio                   BarChart           wall_time, model_version (the latest reproduction's
                            ratio per position, the start first)
    scene/obstacles/<i>     Ellipsoids3D | Boxes3D | Capsules3D  wall_time (the skill's scene;
                            scene/obstacles is cleared at each change); scene/info AnyValues
    live/<robot>/pose       Points3D           wall_time
    live/<robot>/frame      Transform3D + TransformAxes3D  wall_time (the pose's orientation)
    live/<robot>/target     Points3D           wall_time
    live/<robot>/progress   Scalars            wall_time
    live/<robot>/eta        Scalars            wall_time

``/`` carries ``ViewCoordinates`` (RIGHT_HAND_Z_UP unless configured). A 2-D skill is logged
with the 2-D archetypes (LineStrips2D, Points2D, Arrows2D) and its blueprint is a 2-D view.

Every segment of one skill shares the skill's recording id, so merged segments are one
recording. The first segment carries the default blueprint.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from ..adapters.rerun_chunks import send_live
from .events import LiveRows, ReproductionView
from .geometry import CANAL_ALPHA, CorrectionGeometry, FloatArray, ModelGeometry, ObstacleShape

APP_ID = "canal"
_DEMO_COLOR = (90, 140, 240, 255)
_DIRECTRIX_COLOR = (30, 30, 30, 255)
_RING_COLOR = (60, 60, 60, 200)
_AXIS_COLORS = np.array([[230, 50, 50, 255], [50, 200, 50, 255], [50, 80, 240, 255]], np.uint8)
_INSIDE_COLOR = (25, 190, 75, 255)
_OUTSIDE_COLOR = (240, 130, 25, 255)
#: Radius bars: the canal's, or each route's in turn (they share one bar chart).
_RADIUS_COLORS = ((200, 160, 60, 255), (70, 130, 200, 255), (190, 80, 120, 255),
                  (90, 160, 90, 255))
_OBSTACLE_COLOR = (200, 40, 40, 160)


#: Where the eye sits, as a direction from the canal's centre in (right, forward, up) terms:
#: in front, to the side and above, so a curve in a horizontal plane is seen in full.
_EYE_DIRECTION = np.array([0.45, -1.0, 0.75])
#: Vertical field of view Rerun's 3-D view draws with (radians).
_FOV_Y = np.deg2rad(55.0)


def up_axis(coordinates: str) -> FloatArray:
    """The world's up vector for a ``rr.ViewCoordinates`` name (``RIGHT_HAND_Z_UP`` -> +z)."""
    name = coordinates.upper()
    for axis, vector in (("X", (1.0, 0.0, 0.0)), ("Y", (0.0, 1.0, 0.0)), ("Z", (0.0, 0.0, 1.0))):
        if name.endswith(f"{axis}_UP"):
            return np.array(vector)
        if name.endswith(f"{axis}_DOWN"):
            return -np.array(vector)
    return np.array([0.0, 0.0, 1.0])


def framing_eye(points: FloatArray, up: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Eye position and look target that show every point of ``points`` (M, 3) in a 3-D view.

    The eye looks at the centre of the bounding box from :data:`_EYE_DIRECTION` (relative to
    ``up``), far enough for the box's bounding sphere to fit the narrower field of view of a
    view about as wide as high.
    """
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre = (lo + hi) / 2.0
    radius = max(float(np.linalg.norm(hi - lo)) / 2.0, 1e-3)
    up = up / np.linalg.norm(up)
    side = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    side /= np.linalg.norm(side)
    forward = np.cross(up, side)
    direction = _EYE_DIRECTION[0] * side + _EYE_DIRECTION[1] * forward + _EYE_DIRECTION[2] * up
    direction /= np.linalg.norm(direction)
    distance = radius / np.sin(_FOV_Y / 2.0)
    return centre + distance * direction, centre


def review_blueprint(dim: int = 3, *, frame: FloatArray | None = None,
                     coordinates: str = "RIGHT_HAND_Z_UP") -> rrb.Blueprint:
    """What a person sees first: the canal with everything inside it, and plots of its data.

    - "Canal": demos, the see-through canal (directrix, surface, section rings), reproductions
      and live poses; with ``frame`` (points, (M, 3)) the eye is placed to show all of them.
    - "Radius per section": the latest canal's radius along its section index (a bar chart, so
      it reads the same on every timeline).
    - "Ratio per point": the latest reproduction's ratio at each of its positions (the start
      first): how much of the start's offset it keeps along the canal, and where it fades.
    - "Reproductions" and "Live streams": one series per reproduction and per robot along
      ``wall_time``, drawn as points so a single reproduction is visible.
    - The time panel follows ``wall_time`` to its end: the recording opens at its latest state
      (every demo, the latest canal, its reproductions), ready to scrub back.

    A 2-D skill gets a 2-D view (its entities are logged with the 2-D archetypes).
    """
    # Entity filters match whole subtrees (``/**``), not ``*`` inside a path; the plots'
    # scalars and the info values under these trees are not drawn by a spatial view.
    contents = ["+ /**", "- /frames/**", "- /radius/**", "- /ratio/**"]
    if dim == 2:
        spatial: rrb.View = rrb.Spatial2DView(name="Canal", origin="/", contents=contents)
    else:
        eye = None
        if frame is not None and len(frame):
            position, target = framing_eye(frame, up_axis(coordinates))
            eye = rrb.EyeControls3D(position=position, look_target=target,
                                    eye_up=up_axis(coordinates))
        spatial = rrb.Spatial3DView(name="Canal", origin="/", contents=contents,
                                    eye_controls=eye)
    return rrb.Blueprint(
        rrb.Horizontal(
            spatial,
            rrb.Vertical(
                rrb.BarChartView(name="Radius per section (latest canal, section index)",
                                 origin="/model"),
                rrb.BarChartView(name="Ratio per point (latest reproduction, start first)",
                                 origin="/ratio"),
                rrb.Tabs(
                    rrb.TimeSeriesView(name="Reproductions: eta, inside",
                                       origin="/reproductions"),
                    rrb.TimeSeriesView(name="Live streams: progress, eta", origin="/live"),
                ),
            ),
            column_shares=[2, 1],
        ),
        rrb.TimePanel(timeline="wall_time", play_state="following"),
        rrb.SelectionPanel(state="collapsed"),
    )


def _ns(t_ns: int) -> np.datetime64:
    return np.datetime64(int(t_ns), "ns")


def _entity(part: str) -> str:
    return rr.escape_entity_path_part(part)


def view_coordinates(name: str) -> Any:
    """A ``rr.ViewCoordinates`` constant by name (e.g. ``RIGHT_HAND_Z_UP``)."""
    value = getattr(rr.ViewCoordinates, name.upper(), None) if name.isidentifier() else None
    if value is None or name.startswith("_") or callable(value):
        raise ValueError(f"unknown rerun ViewCoordinates {name!r} (e.g. RIGHT_HAND_Z_UP)")
    return value


def rotate(quats: FloatArray, vectors: FloatArray) -> FloatArray:
    """``vectors`` (M, 3) rotated by unit quaternions ``quats`` (M, 4) [qx, qy, qz, qw]."""
    q = quats[:, :3]
    w = quats[:, 3:4]
    t = 2.0 * np.cross(q, vectors)
    return vectors + w * t + np.cross(q, t)


#: About this many orientation triads are drawn along a reproduction.
ORIENTATION_MARKS = 12


class RerunSegment:
    """One open ``.rrd`` segment of a skill's recording (used by the writer thread only).

    The SDK encodes into an in-memory binary stream; :meth:`flush` appends what it encoded to
    the file as one complete RRD stream (header .. footer). The open file is therefore a
    concatenation of complete streams: every flushed part is readable after a crash
    (``rerun rrd verify --check-footers false``), and file I/O errors surface here, in Python,
    instead of in the SDK's file sink (whose ``disconnect()`` can hang once its writer thread
    died of an I/O error). Closing merges the parts into one file with a single footer.

    ``dim`` 2 logs the 2-D archetypes (LineStrips2D, Points2D, Arrows2D) for a 2-D view;
    ``coordinates`` names the ``rr.ViewCoordinates`` of the world (3-D only).
    """

    def __init__(self, path: Path, recording_id: str, skill: str, *, blueprint: bool,
                 dim: int = 3, coordinates: str = "RIGHT_HAND_Z_UP", fast: bool = True) -> None:
        self.path = path
        self.dim = 2 if dim == 2 else 3
        self.fast = fast  # live rows by the adapter's native path when it can
        self.coordinates = coordinates
        self._axes: set[str] = set()  # live frames whose static axes this segment has
        self._file = open(path, "wb")
        self.rec = rr.RecordingStream(APP_ID, recording_id=recording_id)
        self._stream = self.rec.binary_stream()  # type: ignore[misc]  # rerun's stub types it as a free function
        if blueprint:
            self.rec.send_blueprint(review_blueprint(self.dim, coordinates=coordinates),
                                    make_active=False, make_default=True)
        self.rec.send_recording_name(skill)
        if self.dim == 3:
            self.rec.log("/", view_coordinates(coordinates), static=True)
        self._dirty = True

    def _at(self, t_ns: int, version: int | None = None) -> None:
        self._dirty = True
        # Timelines are sticky per stream: reset so one event's model_version never leaks
        # onto the next event's rows.
        self.rec.reset_time()
        self.rec.set_time("wall_time", timestamp=_ns(t_ns))
        if version is not None:
            self.rec.set_time("model_version", sequence=version)

    def _strips(self, strips: list[FloatArray], **kw: Any) -> Any:
        if self.dim == 2:
            return rr.LineStrips2D([s[:, :2] for s in strips], **kw)
        return rr.LineStrips3D(strips, **kw)

    def _points(self, points: FloatArray, **kw: Any) -> Any:
        if self.dim == 2:
            kw.pop("radii", None)
            return rr.Points2D(points[:, :2], radii=[-4.0], **kw)
        return rr.Points3D(points, **kw)

    def _arrows(self, origins: FloatArray, vectors: FloatArray, colors: Any) -> Any:
        if self.dim == 2:
            return rr.Arrows2D(origins=origins[:, :2], vectors=vectors[:, :2], colors=colors)
        return rr.Arrows3D(origins=origins, vectors=vectors, colors=colors)

    # ---- events -----------------------------------------------------------------------------

    def demo_added(self, t_ns: int, demo_id: int, points: FloatArray, positions: FloatArray,
                   timestamps: FloatArray | None, label: str | None,
                   orientations: FloatArray | None = None) -> None:
        """Path, per-sample coordinates, id/label (and orientation triads) of a demonstration."""
        base = f"demos/{demo_id}"
        self._at(t_ns)
        self.rec.log(f"{base}/path", self._strips([points], colors=[_DEMO_COLOR]))
        # The name at the demo's start, not on its path: the viewer puts a strip's label at
        # the mean of its points, and demonstrations of one skill share that mean, so their
        # names were drawn on top of each other; their starts lie apart.
        self.rec.log(f"{base}/start", self._points(
            points[:1], colors=[_DEMO_COLOR], radii=[-3.0],
            labels=[f"demo {demo_id} {label or ''}".strip()]))
        self.rec.log(f"{base}/info", rr.AnyValues(demo_id=demo_id, label=label or "",
                                                  n_samples=len(points)))
        dim = positions.shape[1]
        self.rec.log(f"{base}/position", rr.SeriesLines(names=list("xyz"[:dim])), static=True)
        indexes = [rr.TimeColumn("sample", sequence=np.arange(len(positions)))]
        if timestamps is not None:
            indexes.append(rr.TimeColumn("demo_time", duration=timestamps - timestamps[0]))
        self.rec.send_columns(f"{base}/position", indexes=indexes,
                              columns=rr.Scalars.columns(scalars=positions))
        if orientations is not None and self.dim == 3:
            self._triads(f"{base}/orientation", points, orientations)

    def _triads(self, entity: str, points: FloatArray, quats: FloatArray) -> None:
        """Rotated x/y/z axes (red, green, blue) at about ORIENTATION_MARKS points."""
        idx = np.unique(np.linspace(0, len(points) - 1, min(len(points), ORIENTATION_MARKS))
                        .astype(int))
        span = float(np.linalg.norm(np.ptp(points, axis=0))) or 1.0
        scale = 0.05 * span
        q = quats[idx]
        q = q / np.maximum(np.linalg.norm(q, axis=1, keepdims=True), 1e-12)
        origins = np.repeat(points[idx], 3, axis=0)
        axes = np.tile(np.eye(3) * scale, (len(idx), 1))
        vectors = rotate(np.repeat(q, 3, axis=0), axes)
        self.rec.log(entity, rr.Arrows3D(origins=origins, vectors=vectors,
                                         colors=np.tile(_AXIS_COLORS, (len(idx), 1))))

    def demo_removed(self, t_ns: int, demo_id: int) -> None:
        """Clear the demonstration from this time on."""
        self._at(t_ns)
        self.rec.log(f"demos/{demo_id}", rr.Clear(recursive=True))

    def reproduction_removed(self, t_ns: int, number: int) -> None:
        """Clear reproduction ``number`` from this time on (no longer kept)."""
        self._at(t_ns)
        self.rec.log(f"reproductions/{number}", rr.Clear(recursive=True))

    def model(self, t_ns: int, geo: ModelGeometry) -> None:
        """Directrix, mesh, rings, frames and radius profile of one model version, under its
        own entity ``model/v<version>``; the previous version is cleared from this time on
        (scrub back to see it, or toggle it in the viewer). A model of several routes draws
        each route as its own entity ``model/v<version>/route_<k>`` (directrix, mesh, rings,
        radius, info) and not the canal of all the demonstrations: no reproduction follows
        that one, and its wide tube between the routes would hide them."""
        self._at(t_ns, geo.version)
        base = f"model/v{geo.version}"
        if geo.version > 1:
            self.rec.log(f"model/v{geo.version - 1}", rr.Clear(recursive=True))
            self.rec.log(f"frames/v{geo.version - 1}", rr.Clear(recursive=True))
        drawn = {f"{base}/route_{k}": route for k, route in enumerate(geo.routes)} or {base: geo}
        for k, (path, canal) in enumerate(drawn.items()):
            self.rec.log(f"{path}/directrix", self._strips([canal.directrix],
                                                           colors=[_DIRECTRIX_COLOR]))
            self._surface(path, canal)
            color = _RADIUS_COLORS[k % len(_RADIUS_COLORS)]
            self.rec.log(f"{path}/radius", rr.BarChart(canal.radii, color=color,
                                                       abscissa=np.arange(canal.n_sections)))
        for k, route in enumerate(geo.routes):
            self.rec.log(f"{base}/route_{k}/info", rr.AnyValues(
                version=geo.version, route=k, n_sections=route.n_sections))
        origins = np.vstack([c.frame_origins for c in drawn.values()])
        vectors = np.vstack([c.frame_vectors for c in drawn.values()])
        n_axes = vectors.shape[1]
        self.rec.log(f"frames/v{geo.version}", self._arrows(
            np.repeat(origins, n_axes, axis=0), vectors.reshape(-1, 3),
            np.tile(_AXIS_COLORS[:n_axes], (len(origins), 1))))
        info = rr.AnyValues(version=geo.version, n_sections=geo.n_sections)
        if geo.routes:
            info = rr.AnyValues(version=geo.version, n_sections=geo.n_sections,
                                routes=len(geo.routes))
        self.rec.log(f"{base}/info", info)
        for k, canal in enumerate(drawn.values()):
            radius = f"radius/v{geo.version}" + (f"/route_{k}" if geo.routes else "")
            name = f"v{geo.version}" + (f" route {k}" if geo.routes else "")
            self.rec.log(radius, rr.SeriesLines(names=[name]), static=True)
            self.rec.send_columns(radius, indexes=[rr.TimeColumn("section", sequence=np.arange(
                canal.n_sections))], columns=rr.Scalars.columns(scalars=canal.radii))
        if geo.correction is not None:
            self._correction(geo.version, geo.correction)
        if self.dim == 3:
            # Sent with every model: within a segment the newest blueprint is the active one
            # (a merge of several segments does not keep which was active: docs/recording.md).
            frame = np.vstack([c.vertices for c in drawn.values()])
            self.rec.send_blueprint(review_blueprint(self.dim, frame=frame,
                                                     coordinates=self.coordinates),
                                    make_active=True, make_default=True)

    def _surface(self, base: str, geo: ModelGeometry) -> None:
        """A canal's surface (``base/mesh``) and rings (``base/rings``)."""
        if self.dim == 2:
            # A 2-D canal is a strip: its two boundaries (vertices 2i and 2i+1 per section).
            strip = geo.vertices.reshape(-1, 2, 3)
            self.rec.log(f"{base}/mesh", self._strips([strip[:, 0], strip[:, 1]],
                                                      colors=[_RING_COLOR]))
        else:
            self.rec.log(f"{base}/mesh", rr.Mesh3D(
                vertex_positions=geo.vertices, triangle_indices=geo.faces,
                vertex_normals=geo.vertex_normals,
                vertex_colors=geo.vertex_colors.astype(np.float32),
                albedo_factor=[255, 255, 255, round(255 * CANAL_ALPHA)]))
        self.rec.log(f"{base}/rings", self._strips(list(geo.rings), colors=[_RING_COLOR]))

    def _correction(self, version: int, cor: CorrectionGeometry) -> None:
        """The correction that made model ``version``, under ``corrections/v<version>``: the
        path the person showed, and the changed sections before (grey) and after."""
        base = f"corrections/v{version}"
        color = _INSIDE_COLOR if cor.kind == "include" else _OUTSIDE_COLOR
        self.rec.log(f"{base}/samples", self._strips(
            [cor.samples], colors=[color], labels=[f"{cor.kind} {cor.label}".strip()]))
        self.rec.log(f"{base}/before", self._strips(list(cor.before), colors=[_RING_COLOR]))
        self.rec.log(f"{base}/after", self._strips(list(cor.after), colors=[color]))
        self.rec.log(f"{base}/info", rr.AnyValues(
            kind=cor.kind, label=cor.label, weight=cor.weight, first_section=cor.first,
            last_section=cor.last, corrections=cor.number))

    def scene(self, t_ns: int, version: int, shapes: list[ObstacleShape]) -> None:
        """The skill's scene, replacing the previous one: each obstacle its own entity
        ``scene/obstacles/<i>`` (Ellipsoids3D, Boxes3D, Capsules3D), shown with the canal."""
        self._at(t_ns)
        self.rec.log("scene/obstacles", rr.Clear(recursive=True))
        for i, o in enumerate(shapes):
            path = f"scene/obstacles/{i}"
            if o.kind == "box":
                self.rec.log(path, rr.Boxes3D(centers=[o.center], half_sizes=[o.half_sizes],
                                              quaternions=[rr.Quaternion(xyzw=o.quaternion)],
                                              colors=[_OBSTACLE_COLOR], labels=[o.name],
                                              fill_mode="solid"))
            elif o.kind == "capsule":
                self.rec.log(path, rr.Capsules3D(lengths=[o.length], radii=[o.radius],
                                                 translations=[o.a],
                                                 quaternions=[rr.Quaternion(xyzw=o.quaternion)],
                                                 colors=[_OBSTACLE_COLOR], labels=[o.name]))
            else:
                self.rec.log(path, rr.Ellipsoids3D(centers=[o.center], half_sizes=[o.half_sizes],
                                                   colors=[_OBSTACLE_COLOR], labels=[o.name],
                                                   fill_mode="solid"))
        self.rec.log("scene/info", rr.AnyValues(version=version, obstacles=len(shapes)))

    def reproduction(self, t_ns: int, rep: ReproductionView) -> None:
        """One reproduction under its own entity ``reproductions/<n>``.

        Trajectory, start, eta and inside flag; orientation triads when the reproduction has
        orientations; with ``times``, its moving point on the ``reproduction_time`` timeline.
        """
        rgba = _INSIDE_COLOR if rep.inside else _OUTSIDE_COLOR
        base = f"reproductions/{rep.number}"
        self._at(t_ns, rep.version)
        self.rec.log(f"{base}/path", self._strips([rep.positions], colors=[rgba]))
        self.rec.log(f"{base}/start", self._points(rep.start[None, :], colors=[rgba],
                                                   radii=[-4.0]))
        if rep.orientations is not None and self.dim == 3:
            self._triads(f"{base}/orientation", rep.positions, rep.orientations)
        self._at(t_ns)
        # One value per reproduction: points, since a line needs two
        self.rec.log(f"{base}/eta", rr.SeriesPoints(names=[f"eta {rep.number}"]), static=True)
        self.rec.log(f"{base}/inside", rr.SeriesPoints(names=[f"inside {rep.number}"]),
                     static=True)
        self.rec.log(f"{base}/eta", rr.Scalars(rep.eta))
        self.rec.log(f"{base}/inside", rr.Scalars(float(rep.inside)))
        if rep.ratios is not None:
            # One entity for all reproductions: scrubbing shows each one's profile, and the
            # view is not crowded by the hundreds a skill keeps.
            self._at(t_ns, rep.version)
            self.rec.log("ratio", rr.BarChart(rep.ratios, color=rgba,
                                              abscissa=np.arange(len(rep.ratios))))
        if rep.times is not None:
            index = [rr.TimeColumn("reproduction_time", duration=rep.times - rep.times[0])]
            if self.dim == 2:
                cols = rr.Points2D.columns(positions=rep.positions[:, :2])
            else:
                cols = rr.Points3D.columns(positions=rep.positions)
            self.rec.send_columns(f"{base}/point", indexes=index, columns=cols)
            if rep.orientations is not None and self.dim == 3:
                self.rec.send_columns(f"{base}/point", indexes=index,
                                      columns=rr.Transform3D.columns(
                                          translation=rep.positions,
                                          quaternion=rep.orientations))

    def live(self, rows: LiveRows) -> None:
        """One stream's live rows: poses (point and frame), targets (point, progress, eta),
        one chunk per entity (:func:`canal_service.adapters.rerun_chunks.send_live`)."""
        self._dirty = True
        base = f"live/{_entity(rows.robot)}"
        if self.dim == 3 and base not in self._axes:  # static: once per segment
            self.rec.log(f"{base}/frame", rr.TransformAxes3D(0.1), static=True)
            self._axes.add(base)
        send_live(self.rec, base, rows, self.dim, self.fast)

    # ---- file -------------------------------------------------------------------------------

    def flush(self, timeout_s: float = 5.0) -> None:
        """Append everything logged since the last flush to the file, as one RRD stream."""
        if not self._dirty:
            return
        data = self._stream.read(flush=True, flush_timeout_sec=timeout_s)
        if data:
            self._file.write(data)
        self._file.flush()
        self._dirty = False

    def close(self) -> None:
        """Flush and close the file (still a concatenation: see :func:`merge_rrd`)."""
        try:
            self.flush()
        finally:
            self._file.close()
            self.rec.disconnect()

    def abandon(self) -> None:
        """Close after a write error, without raising (what reached the file stays)."""
        with contextlib.suppress(Exception):
            self._file.close()
        with contextlib.suppress(Exception):
            self.rec.disconnect()

    def discard(self) -> None:
        """Close a segment whose recording is being deleted, without raising: what was
        logged since the last flush goes, on purpose."""
        self.abandon()
        # disconnect() hands what the SDK still batches to the binary stream; read unread,
        # the SDK would warn that it drops it ("Dropping data in BinaryStreamStorage").
        with contextlib.suppress(Exception):
            self._stream.read(flush=False)


def empty_rrd(path: Path, recording_id: str, skill: str, *, dim: int = 3,
              coordinates: str = "RIGHT_HAND_Z_UP") -> None:
    """A finished ``.rrd`` holding only the blueprint (a skill with nothing recorded)."""
    RerunSegment(path, recording_id, skill, blueprint=True, dim=dim,
                 coordinates=coordinates).close()  # one stream: one footer


# ---- the rerun CLI (shipped in the rerun-sdk wheel) ------------------------------------------

def rerun_cli() -> list[str]:
    """Command that runs the ``rerun`` binary of the installed rerun-sdk."""
    import rerun_cli

    exe = Path(rerun_cli.__file__).with_name("rerun.exe" if sys.platform == "win32" else "rerun")
    if exe.exists():
        return [str(exe)]
    return [sys.executable, "-m", "rerun_cli"]


def cli_env(config_home: Path) -> dict[str, str]:
    """Environment for our ``rerun`` subprocesses with analytics off.

    Rerun's documented switch is ``rerun analytics disable``, which writes
    ``$XDG_CONFIG_HOME/rerun/analytics.json``; we point the subprocesses at a config home of
    our own so the user's config is never touched.
    """
    env = dict(os.environ, XDG_CONFIG_HOME=str(config_home))
    if not (config_home / "rerun" / "analytics.json").exists():
        config_home.mkdir(parents=True, exist_ok=True)
        subprocess.run([*rerun_cli(), "analytics", "disable"], env=env, capture_output=True,
                       timeout=60, check=False)
    return env


def merge_rrd(inputs: list[Path], out: Path, env: dict[str, str], *, recover: bool = False) -> None:
    """Merge ``.rrd`` files into one finished file (footer written), atomically.

    With ``recover=True`` an input cut short by a crash contributes what it holds.
    """
    tmp = out.with_name(out.name + ".tmp")
    cmd = [*rerun_cli(), "rrd", "merge", *(str(p) for p in inputs), "-o", str(tmp)]
    if recover:
        cmd.insert(cmd.index("merge") + 1, "--continue-on-error")
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600, check=False)
    if proc.returncode != 0 or not tmp.exists():
        tmp.unlink(missing_ok=True)
        raise RuntimeError(f"rerun rrd merge failed ({proc.returncode}): {proc.stderr[-500:]}")
    tmp.replace(out)

