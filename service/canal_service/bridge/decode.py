"""The pose path's decoding: a drain of samples grouped by stream (an overloaded stream
coalesced to its newest pose), each pose decoded by the codecs' format rule
(:func:`canal_protocol.codecs.pose_format`), demo capture fed on the way."""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Any

from canal_protocol import wire
from canal_protocol.codecs import asks_restart
from canal_protocol.codecs.messages import check_pose_numbers

from .answers import Answers
from .models import ModelEntry
from .streams import ENC_JSON, Job, Stream

_FJSON, _FBIN, _FCDR = wire.FORMAT_JSON, wire.FORMAT_BINARY, wire.FORMAT_CDR
_MAX_BYTES = wire.MAX_POSE_BYTES


def _format_of(encoding: Any, data: bytes) -> int:
    """The codec of a sample (a Zenoh JSON encoding compared as an object, cheaper than
    :func:`canal_protocol.codecs.pose_format`'s string test)."""
    return _FJSON if encoding == ENC_JSON else wire.pose_format(str(encoding), data)


def _kept_of_backlog(samples: list[Any], most: int) -> tuple[int, ...]:
    """The indices of a coalesced backlog's samples that are answered, in order: every one
    that asks for a restart, then the newest. Each restart is made as it would be pose by
    pose (the first after a pause at once, a later one that jumps held until poses agree), so
    a glitch flagged restart behind a real one is held, not obeyed. Past ``most`` restarts,
    the first and the latest ones are kept: the first is the one a pause lets through."""
    restarts = []
    for i in range(len(samples) - 1):
        data = samples[i].payload.to_bytes()
        if asks_restart(_format_of(samples[i].encoding, data), data):
            restarts.append(i)
    if len(restarts) > most > 1:
        restarts = [restarts[0], *restarts[len(restarts) - most + 1 :]]
    return (*restarts, len(samples) - 1)


class Decoder(Answers):
    """The pose path's layer that turns samples into jobs."""

    def decode_batch(self, batch: list[Any]) -> list[list[Job]]:
        """The drain as rounds of jobs: round k holds each stream's k-th pose to answer."""
        if len(batch) == 1:  # the worker keeps up: most drains are one tick's poses
            s = batch[0]
            groups: dict[str, list[Any]] = {str(s.key_expr): batch}
        else:
            groups = {}
            for s in batch:
                key = str(s.key_expr)
                group = groups.get(key)
                if group is None:
                    groups[key] = [s]
                else:
                    group.append(s)
        counts = self.counts
        backlog = self.options.coalesce_backlog
        now = time.monotonic()
        first: list[Job] = []
        rounds: list[list[Job]] = [first]
        streams = self.streams
        decode = self.decode
        for key, samples in groups.items():
            st = streams.get(key)
            if st is None or st.closed:
                found = self.resolve(key)
                if found is None:
                    continue
                if isinstance(found, str):
                    self.parked.setdefault(found, []).extend(samples)
                    counts.parked += len(samples)
                    continue
                if isinstance(found, ModelEntry):
                    for s in samples:
                        self.answer_unknown(key, s, found)
                    continue
                st = found
            st.last_seen = now
            n = len(samples)
            st.rec_poses += n
            if n == 1:
                job = decode(st, samples[0], True)
                if job is not None:
                    first.append(job)
                continue
            keep: frozenset[int] | None = None
            if n > backlog:
                # The newest pose answers the backlog, after the restarts in it: dropped, the
                # re-location a restart asks for would be lost and the newest pose judged
                # against the run the robot has left.
                keep = frozenset(_kept_of_backlog(samples, backlog))
                skipped = n - len(keep)
                st.coalesced += skipped
                st.rec_coalesced += skipped
                counts.coalesced += skipped
            capture = st.capture is not None
            after_gap: set[int] | None = None
            if keep is not None:
                after_gap = st.after_gap = set()
            gap = False
            k = 0
            for i, s in enumerate(samples):
                if keep is not None and i not in keep:
                    gap = True
                    if capture:  # a capture keeps every pose, in order
                        decode(st, s, False)
                    continue
                job = decode(st, s, True)
                if gap and job is not None and after_gap is not None:
                    after_gap.add(id(job[1]))
                    gap = False
                if job is None:
                    continue
                if k == len(rounds):
                    rounds.append([])
                rounds[k].append(job)
                k += 1
        return rounds

    def decode(self, st: Stream, sample: Any, answer: bool) -> Job | None:
        """One sample as a pose job, or None (answered with an error, or not to answer)."""
        data = sample.payload.to_bytes()
        encoding = sample.encoding
        ros = None
        if answer:
            self.counts.poses += 1
        try:
            if len(data) > _MAX_BYTES:
                fmt = _format_of(encoding, data)
                raise wire.WireError("bad_payload", f"expected a pose of at most {_MAX_BYTES} "
                                                    f"bytes, got {len(data)}")
            if encoding == ENC_JSON:  # an object comparison, cheaper than str() (0.15 us)
                fmt = _FJSON
                pose = wire.decode_pose_json(data)
            else:
                fmt = wire.pose_format(str(encoding), data)
                pose, ros = wire.decode_pose_as(fmt, data, st.cdr_seq)
                if ros is not None:
                    st.cdr_seq += 1
                    # a PoseStamped's numbers, checked as the other codecs check theirs (the
                    # codec itself also reads uploads, whose checks are the REST API's)
                    check_pose_numbers(pose.position, pose.orientation, None)
        except wire.WireError as exc:
            if answer:
                self.error(st, exc.seq, exc.key, exc.message, fmt)
            return None
        st.last_seq = pose.seq
        if st.capture is not None:
            kept = pose
            if ros is not None and len(pose.position) == 3 and self.models.entry(st.skill).dim == 2:
                # a PoseStamped always has z: a 2-D skill's capture keeps x, y, as tracking
                # does (the answer still carries the pose's own z)
                kept = replace(pose, position=pose.position[:2])
            with st.lock:
                if st.capture is not None and pose.seq >= st.capture_from:
                    st.capture.append(kept)
        if not answer:
            return None
        return st, pose, fmt, ros
