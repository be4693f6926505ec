"""The pose path's answers: each stepped pose's target put in the format the pose came in
(binary, JSON, or a ROS 2 PoseStamped with the status on its own key), errors, and an
unknown skill's answer.

The recording tap's row rule runs inside :meth:`Answers.answer_all`'s loop (a row when due,
or when the status, ``inside`` or ``done`` flips): a call per pose there would cost the
one-robot bridge measurably; :mod:`.tap` hands the rows on.
"""

from __future__ import annotations

import math
from typing import Any

from canal_protocol import keys as keyspace
from canal_protocol import wire

from .models import ModelEntry
from .streams import ENC_BINARY, ENC_CDR, ENC_JSON, Job, Stream, StreamTable

_OK = wire.STATUS_CODES["ok"]
_OUTSIDE = wire.STATUS_CODES["outside_canal"]
#: obstacle status of a bank row (canal_core.tracker_obstacles) -> the answer's status key, code
_OBSTACLE_KEYS = ("ok", "detour", "blocked", "in_obstacle")
_OBSTACLE_CODES = tuple(wire.STATUS_CODES[k] for k in _OBSTACLE_KEYS)
_FJSON, _FBIN, _FCDR = wire.FORMAT_JSON, wire.FORMAT_BINARY, wire.FORMAT_CDR
_DONE_ETA = 1.0 + 1e-9
_pack_json = wire.pack_target_json


class Answers(StreamTable):
    """The pose path's layer that publishes answers (see the module docstring)."""

    def answer_all(self, entry: ModelEntry, group: list[Job], rows: list[list[float]],
                   obstacles: list[int] | None = None) -> None:
        """Publish the answer of each job of one bank pass (and keep it for the recording
        when it is due). ``rows`` are the pass's packed answers: target (D), progress, eta,
        section, inside, done, velocity (D), orientation (4); ``obstacles`` each row's
        obstacle status (0 none, else ``detour``, ``blocked``, ``in_obstacle``, which is
        the answer's status).

        One loop with no call per answer but the encoder's and the put: on a one-robot
        bridge this runs once a millisecond on cold caches, where every Python call and
        temporary counts (the lean path halved a cold pose's cost)."""
        d = entry.dim
        v0, o0 = d + 5, 2 * d + 5
        bank = entry.bank
        assert bank is not None
        with_velocity, with_orientation = bank.has_velocity, bank.has_orientation
        version = entry.version
        route = entry.route  # wire.NO_ROUTE for a model of one route: no "route" key
        binary_route = wire.NO_ROUTE if route is None else route  # the canal of all: none
        counts = self.counts
        period = self.record_period_ns
        now = self.now_ns
        for i, ((st, pose, fmt, ros), row) in enumerate(zip(group, rows, strict=True)):
            target = row[:d]
            progress = row[d]
            eta = row[d + 1]
            section = int(row[d + 2])
            inside = row[d + 3] != 0.0
            # "done" only counts at the end *and* within the last sections: a pose far
            # beyond the last plane (50, 50, 50; 1e308) is lost, not finished
            done = row[d + 4] != 0.0 and eta <= _DONE_ETA
            velocity = row[v0:o0] if with_velocity else None
            if with_orientation:
                orientation: list[float] | None = row[o0:o0 + 4]
            elif pose.orientation is not None:
                orientation = list(pose.orientation)
            else:
                orientation = None
            if inside or done:
                code = _OK
                status = "ok"
            else:
                code = _OUTSIDE
                status = "outside_canal"
                progress, target, eta = self._outside(entry, row, section, target, eta)
                if progress < st.progress:
                    progress = st.progress
            st.progress = progress
            if obstacles is not None and obstacles[i]:
                status = _OBSTACLE_KEYS[obstacles[i]]
                code = _OBSTACLE_CODES[obstacles[i]]
            st.rec_answered += 1
            if period is not None and (now >= st.rec_next or code != st.rec_state[0]
                                       or inside != st.rec_state[1] or done != st.rec_state[2]):
                # a row when due, or when the status, inside or done flips
                st.rec_next = now + period
                st.rec_state = (code, inside, done)
                position = pose.position
                if len(position) != d:
                    # a PoseStamped on a 2-D skill: its z is passed through in the answer,
                    # not tracked; a stream's rows have the skill's dimension, or no batch
                    # could carry them
                    position = position[:d]
                st.rec_rows.append((now, position, pose.orientation, target, orientation,
                                    progress, eta, section, inside, done, status, binary_route))
            if fmt == _FJSON:  # the publisher's default encoding
                st.publisher.put(_pack_json(
                    pose.seq, status, target, progress, eta, section, inside, done,
                    version, orientation, velocity, st.coalesced, route))
            elif fmt == _FBIN:
                st.publisher.put(wire.pack_target(
                    pose.seq, code, target, progress, eta, section, inside, done, version,
                    orientation, velocity, st.coalesced, binary_route), encoding=ENC_BINARY)
            else:
                self._answer_cdr(st, pose, ros, entry, target, progress, eta, section, inside,
                                 done, orientation, status)
        counts.targets += len(rows)

    def _outside(self, entry: ModelEntry, row: list[float], section: int,
                 target: list[float], eta: float) -> tuple[float, list[float], float]:
        """An answer that is neither inside nor done: its progress, target and eta."""
        self.counts.errors["outside_canal"] += 1
        n = entry.canal.n_sections
        d = entry.dim
        # lost beyond the end is not the end reached: progress is the located section's
        progress = section / max(n - 1, 1) if row[d + 4] != 0.0 else row[d]
        if not all(map(math.isfinite, target)):
            # overflowed: the way back in is the section ahead's centre
            target = entry.canal.directrix[min(section + self.options.lookahead,
                                               n - 1)].tolist()
        if not math.isfinite(eta):
            eta = 1e308
        return progress, target, eta

    def _answer_cdr(self, st: Stream, pose: wire.Pose, ros: Any, entry: ModelEntry,
                    target: list[float], progress: float, eta: float, section: int,
                    inside: bool, done: bool, orientation: list[float] | None,
                    status: str) -> None:
        """A ROS 2 robot's answer: a PoseStamped on the target key, the status (JSON) on
        the status key when it changes."""
        position = list(target)
        if len(position) == 2:
            position.append(pose.position[2])
        st.publisher.put(wire.encode_pose_stamped_cdr(ros, position, orientation),
                         encoding=ENC_CDR)
        if status != st.cdr_status:
            st.cdr_status = status
            self.session.put(st.status_key, wire.target_json(wire.Target(
                pose.seq, status, tuple(position[:entry.dim]), progress, eta, section,
                inside, done, entry.version, None,
                None if orientation is None else tuple(orientation),  # type: ignore[arg-type]
                coalesced=st.coalesced,
                route=None if entry.route == wire.NO_ROUTE else entry.route)), encoding=ENC_JSON)

    def error(self, st: Stream, seq: int | None, key: str, message: str | None,
              fmt: int) -> None:
        # the progress the stream had reached: a glitch held back does not move it, and a
        # client showing progress should not see it fall to 0 and back
        answer = wire.Target(seq=seq, status=key, message=message, coalesced=st.coalesced,
                             progress=st.progress)
        if fmt == _FJSON:
            st.publisher.put(wire.target_json(answer), encoding=ENC_JSON)
        elif fmt == _FBIN:
            st.publisher.put(wire.encode_target(answer), encoding=ENC_BINARY)
        else:
            st.cdr_status = key
            self.session.put(st.status_key, wire.target_json(answer), encoding=ENC_JSON)
        self.counts.targets += 1
        self.counts.errors[key] += 1
        st.rec_errors += 1

    def answer_unknown(self, key: str, sample: Any, entry: ModelEntry) -> None:
        """The answer to a pose that has no stream (an unknown skill, a new robot past
        ``max_streams``), on a put without a declared publisher."""
        self.counts.poses += 1
        data = sample.payload.to_bytes()
        encoding = str(sample.encoding)
        seq: int | None = None
        fmt = wire.pose_format(encoding, data)
        if fmt != _FCDR:
            try:
                seq = wire.decode_pose_as(fmt, data)[0].seq
            except wire.WireError as exc:  # the seq when it could be read
                seq = exc.seq
        answer = wire.Target(seq=seq, status=entry.status, message=entry.message)
        base = key[: -len(keyspace.POSE)]
        if fmt == _FJSON:
            self.session.put(base + keyspace.TARGET, wire.target_json(answer), encoding=ENC_JSON)
        elif fmt == _FBIN:
            self.session.put(base + keyspace.TARGET, wire.encode_target(answer),
                             encoding=ENC_BINARY)
        else:
            self.session.put(base + keyspace.STATUS, wire.target_json(answer),
                             encoding=ENC_JSON)
        self.counts.targets += 1
        self.counts.errors[entry.status] += 1
        if self.record_period_ns is not None:
            self.counts.unknown += 1  # no stream, nothing to record: decimated
