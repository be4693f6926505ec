"""The MCAP side of a skill's recording: one Writer per segment, Foxglove messages, merge, repair.

Topics (all JSON, see :mod:`.foxglove` for the schemas)::

    /tf                        foxglove.FrameTransform   world -> canal (per segment),
                                                          canal -> robot/<name> (live)
    /canal/demos               foxglove.SceneUpdate      demo/<id> line; deletions on removal
    /canal/demo_poses/<id>     foxglove.PosesInFrame     a demo's poses (when it has orientations)
    /canal/model               foxglove.SceneUpdate      canal/mesh, directrix, rings, frames (a
                                                          model of several routes:
                                                          canal/route_<k>/..., no canal/mesh)
    /canal/model_info          canal.ModelInfo           version, radii and arclength arrays
    /canal/corrections         foxglove.SceneUpdate      correction/v<k>: the path of the
                               correction that made version k, the changed sections before
                               and after
    /canal/correction_info     canal.CorrectionInfo      kind, label, weight, span
    /canal/reproductions       foxglove.SceneUpdate      reproduction/<n> line and start (one
                                                          entity per reproduction)
    /canal/reproduction_result canal.ReproductionResult  eta, inside, times, ...
    /canal/reproduction_poses  foxglove.PosesInFrame     a reproduction's poses (when it has
                                                          orientations)
    /canal/scene               foxglove.SceneUpdate      scene/<i>: each obstacle of the skill's
                                                          scene (spheres, cubes, a capsule's
                                                          cylinder + spheres), all replaced per change
    /live/<robot>/pose         foxglove.PoseInFrame      the robot's orientation (identity when
                                                          the pose had none)
    /live/<robot>/target       foxglove.PoseInFrame      the target's orientation (likewise)
    /live/<robot>/state        canal.TrackerState        progress, eta, inside, done

Files are chunked and zstd-compressed with message indexes and a summary. A segment's chunk
is closed at every recorder flush, so a crash loses at most one flush interval.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np
from mcap.reader import NonSeekingReader, make_reader
from mcap.records import Channel, Message, Schema
from mcap.writer import CompressionType, Writer
from numpy.typing import NDArray

from ..adapters.mcap_writer import pair_writer
from . import foxglove as fx
from .events import LiveRows, ReproductionView
from .geometry import CANAL_ALPHA, CorrectionGeometry, ModelGeometry, ObstacleShape

CHUNK_SIZE = 1024 * 1024
LIBRARY = "canal-recorder"
_DEMO_COLOR = (0.35, 0.55, 0.95, 1.0)
_DIRECTRIX_COLOR = (0.1, 0.1, 0.1, 1.0)
_RING_COLOR = (0.2, 0.2, 0.2, 0.8)
_AXIS_COLORS = np.array([[0.9, 0.2, 0.2, 1.0], [0.2, 0.8, 0.2, 1.0], [0.2, 0.3, 0.95, 1.0]])
_INSIDE_COLOR = (0.1, 0.75, 0.3, 1.0)
_OUTSIDE_COLOR = (0.95, 0.5, 0.1, 1.0)
_OBSTACLE_COLOR = (0.8, 0.15, 0.15, 0.6)


def _open_writer(path: Path) -> tuple[IO[bytes], Writer]:
    stream = open(path, "wb")
    writer = Writer(stream, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD)
    writer.start(profile="", library=LIBRARY)
    return stream, writer


class _Channels:
    """Schema and channel ids of one Writer, registered on first use."""

    def __init__(self, writer: Writer) -> None:
        self._writer = writer
        self._schemas: dict[tuple[str, str, bytes], int] = {}
        self._channels: dict[tuple[str, int, str], int] = {}

    def channel(self, topic: str, schema_name: str, *, schema_encoding: str = "jsonschema",
                schema_data: bytes | None = None, message_encoding: str = "json") -> int:
        data = fx.schema_bytes(schema_name) if schema_data is None else schema_data
        skey = (schema_name, schema_encoding, data)
        sid = self._schemas.get(skey)
        if sid is None:
            sid = self._writer.register_schema(schema_name, schema_encoding, data)
            self._schemas[skey] = sid
        ckey = (topic, sid, message_encoding)
        cid = self._channels.get(ckey)
        if cid is None:
            cid = self._writer.register_channel(topic, message_encoding, sid)
            self._channels[ckey] = cid
        return cid


class McapSegment:
    """One open MCAP segment of a skill's recording (used by the writer thread only)."""

    def __init__(self, path: Path, t_ns: int, fast: bool = True) -> None:
        self.path = path
        self._stream, self._writer = _open_writer(path)
        self._channels = _Channels(self._writer)
        self._pairs = pair_writer(self._writer, fast)
        self._dirty = False
        self._write("/tf", "foxglove.FrameTransform", t_ns,
                    fx.frame_transform(t_ns, fx.WORLD_FRAME, fx.CANAL_FRAME))

    # ---- events -----------------------------------------------------------------------------

    def demo_added(self, t_ns: int, demo_id: int, points: np.ndarray, label: str | None,
                   orientations: np.ndarray | None = None) -> None:
        """A demo/<id> line entity; ``points`` (T, 3); its poses when it has orientations."""
        ent = fx.entity(t_ns, f"demo/{demo_id}", lines=[fx.line(points, _DEMO_COLOR)],
                        metadata={"demo_id": demo_id, "label": label or "",
                                  "n_samples": len(points)})
        self._write("/canal/demos", "foxglove.SceneUpdate", t_ns, fx.scene_update([ent]))
        if orientations is not None and len(orientations) == len(points):
            self._write(f"/canal/demo_poses/{demo_id}", "foxglove.PosesInFrame", t_ns,
                        fx.poses_in_frame(t_ns, points, orientations))

    def demo_removed(self, t_ns: int, demo_id: int) -> None:
        """Delete the demo/<id> entity."""
        self._write("/canal/demos", "foxglove.SceneUpdate", t_ns,
                    fx.scene_update(deletions=[(t_ns, f"demo/{demo_id}")]))

    def reproduction_removed(self, t_ns: int, number: int) -> None:
        """Delete the reproduction/<n> entity (no longer kept)."""
        self._write("/canal/reproductions", "foxglove.SceneUpdate", t_ns,
                    fx.scene_update(deletions=[(t_ns, f"reproduction/{number}")]))

    def model(self, t_ns: int, geo: ModelGeometry) -> None:
        """Mesh, directrix, rings and frames of one model version (replacing the previous). A
        model of several routes draws each route as its own entities ``canal/route_<k>/mesh``,
        ``.../directrix``, ``.../rings`` (metadata ``route``) and not the canal of all the
        demonstrations, which no reproduction follows; its info says ``routes``."""
        meta = {"version": geo.version, "n_sections": geo.n_sections}
        drawn = {f"canal/route_{k}": (route, {**meta, "route": k, "n_sections": route.n_sections})
                 for k, route in enumerate(geo.routes)} or {"canal": (geo, meta)}
        entities = []
        for base, (canal, canal_meta) in drawn.items():
            see_through = canal.vertex_colors.copy()
            see_through[:, 3] = CANAL_ALPHA
            # Rings as one LINE_LIST: consecutive ring points pair up into segments.
            ring_segments = np.stack([canal.rings[:, :-1], canal.rings[:, 1:]],
                                     axis=2).reshape(-1, 3)
            entities += [
                fx.entity(t_ns, f"{base}/mesh", metadata=canal_meta, triangle_lists=[
                    fx.triangles(canal.vertices, canal.faces, see_through)]),
                fx.entity(t_ns, f"{base}/directrix", metadata=canal_meta,
                          lines=[fx.line(canal.directrix, _DIRECTRIX_COLOR, thickness=3.0)]),
                fx.entity(t_ns, f"{base}/rings", metadata=canal_meta, lines=[
                    fx.line(ring_segments, _RING_COLOR, thickness=1.0, kind=fx.LINE_LIST)]),
            ]
        origins = np.vstack([c.frame_origins for c, _ in drawn.values()])
        vectors = np.vstack([c.frame_vectors for c, _ in drawn.values()])
        n_axes = vectors.shape[1]
        tails = np.repeat(origins, n_axes, axis=0)
        segments = np.stack([tails, tails + vectors.reshape(-1, 3)], axis=1).reshape(-1, 3)
        axis_colors = np.repeat(np.tile(_AXIS_COLORS[:n_axes], (len(origins), 1)), 2, axis=0)
        entities.append(fx.entity(t_ns, "canal/frames", metadata=meta, lines=[
            fx.line(segments, _DIRECTRIX_COLOR, thickness=2.0, kind=fx.LINE_LIST,
                    colors=axis_colors)]))
        # Cleared first: the previous version may have had other routes (or a canal of all).
        self._write("/canal/model", "foxglove.SceneUpdate", t_ns,
                    fx.scene_update(entities, clear_at=t_ns))
        extra = {"routes": len(geo.routes)} if geo.routes else {}
        self._write("/canal/model_info", "canal.ModelInfo", t_ns, fx.plain(
            t_ns, version=geo.version, n_sections=geo.n_sections, radii=geo.radii,
            arclength=geo.arclength, **extra))
        if geo.correction is not None:
            self._correction(t_ns, geo.version, geo.correction)

    def _correction(self, t_ns: int, version: int, cor: CorrectionGeometry) -> None:
        """The correction that made model ``version`` as its own entity
        ``correction/v<version>``: the path the person showed (a line strip) and the changed
        sections before (grey) and after (a line list each), with its info message."""
        color = _INSIDE_COLOR if cor.kind == "include" else _OUTSIDE_COLOR

        def segments(rings: np.ndarray) -> np.ndarray:
            return np.stack([rings[:, :-1], rings[:, 1:]], axis=2).reshape(-1, 3)

        meta = {"model_version": version, "kind": cor.kind, "label": cor.label,
                "first_section": cor.first, "last_section": cor.last}
        ent = fx.entity(t_ns, f"correction/v{version}", metadata=meta, lines=[
            fx.line(cor.samples, color, thickness=3.0),
            fx.line(segments(cor.before), _RING_COLOR, thickness=1.0, kind=fx.LINE_LIST),
            fx.line(segments(cor.after), color, thickness=1.0, kind=fx.LINE_LIST)])
        self._write("/canal/corrections", "foxglove.SceneUpdate", t_ns, fx.scene_update([ent]))
        self._write("/canal/correction_info", "canal.CorrectionInfo", t_ns, fx.plain(
            t_ns, model_version=version, kind=cor.kind, label=cor.label, weight=cor.weight,
            first_section=cor.first, last_section=cor.last, corrections=cor.number,
            n_samples=len(cor.samples)))

    def scene(self, t_ns: int, version: int, shapes: list[ObstacleShape]) -> None:
        """The skill's scene as one ``scene/<i>`` entity per obstacle (sphere, cube, or a
        capsule's cylinder and end spheres), replacing the previous scene's."""
        entities = []
        for i, o in enumerate(shapes):
            meta = {"version": version, "kind": o.kind, "name": o.name}
            if o.kind == "box":
                ent = fx.entity(t_ns, f"scene/{i}", metadata=meta, cubes=[
                    fx.cube(o.center, 2.0 * o.half_sizes, o.quaternion, _OBSTACLE_COLOR)])
            elif o.kind == "capsule":
                d = 2.0 * o.radius
                ent = fx.entity(t_ns, f"scene/{i}", metadata=meta, cylinders=[
                    fx.cylinder(o.center, d, o.length, o.quaternion, _OBSTACLE_COLOR)],
                    spheres=[fx.sphere(o.a, (d, d, d), _OBSTACLE_COLOR),
                             fx.sphere(o.b, (d, d, d), _OBSTACLE_COLOR)])
            else:
                ent = fx.entity(t_ns, f"scene/{i}", metadata=meta, spheres=[
                    fx.sphere(o.center, 2.0 * o.half_sizes, _OBSTACLE_COLOR)])
            entities.append(ent)
        # Every earlier obstacle goes first (this topic holds the scene only): a smaller
        # scene leaves none behind.
        self._write("/canal/scene", "foxglove.SceneUpdate", t_ns,
                    fx.scene_update(entities, clear_at=t_ns))

    def reproduction(self, t_ns: int, rep: ReproductionView) -> None:
        """One reproduction as its own entity ``reproduction/<n>`` (green inside, orange
        outside), its result, and its poses (real orientations when it has them)."""
        rgba = _INSIDE_COLOR if rep.inside else _OUTSIDE_COLOR
        ent = fx.entity(t_ns, f"reproduction/{rep.number}", lines=[
            fx.line(rep.positions, rgba, thickness=3.0),
            fx.line(np.stack([rep.start, rep.positions[0]]), rgba, thickness=8.0)],
            metadata={"model_version": rep.version, "inside": rep.inside, "eta": rep.eta,
                      "number": rep.number})
        self._write("/canal/reproductions", "foxglove.SceneUpdate", t_ns, fx.scene_update([ent]))
        x, y, z = rep.start.tolist()
        self._write("/canal/reproduction_result", "canal.ReproductionResult", t_ns, fx.plain(
            t_ns, model_version=rep.version, eta=rep.eta, inside=rep.inside,
            projected=rep.projected, section_index=rep.section_index, number=rep.number,
            start={"x": x, "y": y, "z": z}, n_points=len(rep.positions),
            times=rep.times,
            ratios=rep.ratios))
        if rep.orientations is not None:
            self._write("/canal/reproduction_poses", "foxglove.PosesInFrame", t_ns,
                        fx.poses_in_frame(t_ns, rep.positions, rep.orientations))

    def live(self, rows: LiveRows) -> None:
        """One stream's live rows: each row's pose with the robot's frame (/tf), then each
        row's target with the tracker state."""
        robot = rows.robot
        t = rows.t_ns
        channel = self._channels.channel
        poses, frames = fx.pose_and_frame_messages(rows.t_ns, rows.position, rows.orientation,
                                                   f"robot/{robot}")
        self._add_pairs(channel(f"/live/{robot}/pose", "foxglove.PoseInFrame"), poses,
                        channel("/tf", "foxglove.FrameTransform"), frames, t)
        targets = fx.pose_in_frame_messages(rows.t_ns, rows.target, rows.target_orientation)
        states = fx.tracker_state_messages(rows.t_ns, robot, rows.progress, rows.eta,
                                           rows.section_index, rows.inside, rows.done,
                                           rows.route)
        self._add_pairs(channel(f"/live/{robot}/target", "foxglove.PoseInFrame"), targets,
                        channel(f"/live/{robot}/state", "canal.TrackerState"), states, t)

    def _add_pairs(self, first: int, firsts: list[bytes], second: int, seconds: list[bytes],
                   t_ns: NDArray[np.int64]) -> None:
        """Messages on two channels, interleaved (first, second) per row at ``t_ns``: all
        records in one write when the mcap adapter can (:mod:`canal_service.adapters.mcap_writer`)."""
        self._dirty = True
        self._pairs(first, firsts, second, seconds, t_ns)

    # ---- file -------------------------------------------------------------------------------

    def flush(self) -> None:
        """Close the open chunk and push it to the OS (a crash keeps everything before)."""
        if self._dirty:
            self._writer.flush()  # type: ignore[no-untyped-call]  # mcap's Writer is untyped
            self._dirty = False

    def close(self) -> None:
        """Write the summary and close the file."""
        try:
            self._writer.finish()  # type: ignore[no-untyped-call]
        finally:
            self._stream.close()

    def abandon(self) -> None:
        """Close the file without finishing it (after a write error)."""
        with contextlib.suppress(Exception):
            self._stream.close()

    def _write(self, topic: str, schema_name: str, t_ns: int, data: bytes) -> None:
        cid = self._channels.channel(topic, schema_name)
        self._writer.add_message(cid, log_time=t_ns, data=data, publish_time=t_ns)
        self._dirty = True


# ---- whole files ----------------------------------------------------------------------------

def empty_mcap(path: Path, t_ns: int) -> None:
    """A finished MCAP with only the world -> canal frame (a skill with nothing recorded)."""
    McapSegment(path, t_ns).close()


def recovered_messages(stream: IO[bytes]) -> Iterator[tuple[Schema | None, Channel, Message]]:
    """Messages of an MCAP that may end mid-record (a crashed writer), in file order.

    Reads linearly with the non-seeking reader (an unfinished file has no summary) and stops
    quietly at the first record the crash cut short.
    """
    messages = NonSeekingReader(stream, validate_crcs=True).iter_messages(log_time_order=False)
    while True:
        try:
            item = next(messages)
        except StopIteration:
            return
        except Exception:  # EndOfFile, a short struct read, a CRC error: where the crash cut
            return
        yield item


def _copy(messages: Iterable[tuple[Schema | None, Channel, Message]], out: Writer,
          channels: _Channels) -> int:
    n = 0
    for schema, channel, message in messages:
        cid = channels.channel(
            channel.topic, schema.name if schema else "",
            schema_encoding=schema.encoding if schema else "",
            schema_data=schema.data if schema else b"",
            message_encoding=channel.message_encoding)
        out.add_message(cid, log_time=message.log_time, data=message.data,
                        publish_time=message.publish_time, sequence=message.sequence)
        n += 1
    return n


def merge_mcap(inputs: list[Path], out: Path, *, recover: bool = False) -> int:
    """Write the messages of ``inputs`` (in order) to one finished MCAP; returns the count.

    Parameters
    ----------
    inputs : list of Path
        Finished segments, or with ``recover=True`` possibly unfinished ones.
    out : Path
        Written atomically (temporary file, then rename).
    """
    tmp = out.with_name(out.name + ".tmp")
    stream, writer = _open_writer(tmp)
    try:
        channels = _Channels(writer)
        n = 0
        for path in inputs:
            with open(path, "rb") as f:
                if recover:
                    n += _copy(recovered_messages(f), writer, channels)
                else:
                    n += _copy(make_reader(f).iter_messages(log_time_order=False), writer, channels)
        writer.finish()  # type: ignore[no-untyped-call]
        stream.flush()
        os.fsync(stream.fileno())
    except BaseException:
        stream.close()
        tmp.unlink(missing_ok=True)
        raise
    stream.close()
    tmp.replace(out)
    return n


def summary_counts(path: Path) -> dict[str, Any]:
    """Channels, schemas and message counts per topic from a finished file's summary."""
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    if summary is None:
        return {"topics": {}, "schemas": {}}
    counts = summary.statistics.channel_message_counts if summary.statistics else {}
    return {
        "topics": {c.topic: counts.get(cid, 0) for cid, c in summary.channels.items()},
        "schemas": {c.topic: summary.schemas[c.schema_id].name
                    for c in summary.channels.values() if c.schema_id},
    }
