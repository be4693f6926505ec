"""What a person captures on a live stream: a demonstration, a correction, a steered run kept.

The queries ``demo/start|stop``, ``correction/start|stop`` and ``steer/keep`` under
``{prefix}/{skill}/{robot}/`` (their bodies checked in :mod:`.queries`) begin and end a
capture on the stream. The worker adds the stream's poses to it as they come
(:mod:`.posepath`); the stop stores them as a demonstration or a correction of the skill
instance the capture began on, on the control thread, never on the pose path.

A stop refused for what was captured (too few poses, timestamps that do not advance, the
database away) leaves the capture open: the poses are not lost, the person may go on and
stop again, or start the capture over (a start during a capture of its own kind does, and
says how many poses it discards; one during a steered run ends the run, to keep after).
Only a stop refused because the skill the capture began on is gone, or a demonstration
longer than an upload may be, ends it: nothing could ever store it.

A capture holds at most ``BridgeOptions.capture_max`` poses (:class:`.streams.Capture`);
a correction or a steered run with more than a correction holds is thinned evenly to that
(:func:`thinned`), the reply's notes saying so.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import orjson
from pydantic import ValidationError

from canal_core import bounds
from canal_core.options import CORRECTION_KINDS, MAX_CORRECTION_SAMPLES
from canal_core.routes import way_of
from canal_protocol.schemas import CorrectionIn

from ..errors import InvalidInput, ServiceError, SkillReplaced, error_type, pydantic_detail
from ..service import CanalService
from ..storage import repository as repo
from ..validation import check_demonstration
from .models import ModelTable
from .streams import ENC_JSON, Capture, Stream, end_steered_run_locked, new_capture

log = logging.getLogger("canal_service.bridge")

#: How long a stop with ``last_seq`` waits for the worker to see that pose.
_STOP_WAIT_S = 2.0
#: ... and stops waiting when no pose of the stream came for this long.
_STALL_S = 0.5
#: ... and waits only for a pose at most this many poses ahead of the last one seen (a
#: second of poses at 1 kHz): the poses still on their way, not ones never sent.
_IN_FLIGHT = 1000


#: the capture kinds each stop ends (``capture_kind`` None: a demonstration)
_STOP_KINDS: dict[tuple[str, str], tuple[str | None, ...]] = {
    ("demo", "stop"): (None,), ("correction", "stop"): CORRECTION_KINDS}


class Captures:
    """Begin, end and store the captures of live streams for a bridge."""

    def __init__(self, service: CanalService, models: ModelTable,
                 route_of: Callable[[Stream], int | None]) -> None:
        self.service = service
        self.models = models
        #: the route a stream follows in its skill's model now (the bridge's)
        self.route_of = route_of

    def answer(self, query: Any, st: Stream, what: tuple[str, str], body: dict[str, Any]) -> None:
        """Answer the query ``what`` (a key of :data:`.queries.STREAM_QUERIES`) on the stream,
        its body already checked."""
        if what == ("demo", "start"):
            self._capture_start(query, st, body, None)
        elif what == ("demo", "stop"):
            self._demo_stop(query, st, body)
        elif what == ("correction", "start"):
            self._correction_start(query, st, body)
        elif what == ("correction", "stop"):
            self._correction_stop(query, st, body)
        else:
            self._steer_keep(query, st, body)

    def holds(self, st: Stream, what: tuple[str, str]) -> bool:
        """Whether the stream holds a capture, begun on a skill, that the query ``what``
        ends: its stop is answered even when that skill is gone since."""
        with st.lock:
            kinds = _STOP_KINDS.get(what)
            if kinds is not None:
                return st.capture is not None and st.capture_kind in kinds \
                    and st.capture_instance is not None
            if what == ("steer", "keep"):
                if st.capture is not None and st.capture_kind == "steer":
                    return st.capture_instance is not None
                return bool(st.steered) and st.steered_instance is not None
            return False

    def begin_steered(self, st: Stream) -> None:
        """The stream's first steering input: the run from here on is kept (``steer/keep``)
        unless a capture runs."""
        instance = self.skill_instance(st.skill)
        with st.lock:
            if st.capture is None:
                st.capture, st.capture_from = new_capture(st), st.last_seq + 1
                st.capture_kind, st.capture_label = "steer", None
                st.capture_instance = instance

    def _capture_start(self, query: Any, st: Stream, body: dict[str, Any],
                       kind: str | None, weight: float = 1.0) -> None:
        from_seq = body.get("from_seq")
        label = body.get("label")
        instance = self.skill_instance(st.skill)
        if instance is None:
            reply_error(query, "not_found", f"unknown skill '{st.skill}'", "skill")
            return
        with st.lock:
            # a capture begun on a skill deleted since is over: it is not in the way
            if (st.capture is not None and st.capture_kind not in (kind, "steer")
                    and st.capture_instance == instance):
                busy = "a demonstration" if st.capture_kind is None else "a correction"
                # the field names what is being captured: what to stop first
                reply_error(query, "conflict", f"{busy} is being captured on this stream; "
                             "stop it first", "demo" if st.capture_kind is None else "correction")
                return
            # a steered run is not thrown away by a capture begun over it: it ends there, the
            # last steered run, for steer/keep to keep after the capture as before it
            end_steered_run_locked(st, st.route, st.route_serial)
            # what a start over throws away, said in the reply: never a silent loss
            discarded = 0 if st.capture is None else st.capture.came
            st.capture = new_capture(st)
            st.capture_from = int(from_seq) if isinstance(from_seq, int) else st.last_seq + 1
            st.capture_label = label if isinstance(label, str) else None
            st.capture_kind, st.capture_weight = kind, weight
            st.capture_instance = instance
        query.reply(query.key_expr, orjson.dumps({"capturing": True,
                                                  "from_seq": st.capture_from,
                                                  "discarded": discarded}),
                    encoding=ENC_JSON)

    def _capture_stop(self, query: Any, st: Stream, body: dict[str, Any],
                      kinds: tuple[str | None, ...], what: str
                      ) -> tuple[Capture, list[Any], str] | None:
        """The capture (still open: :func:`_end` ends it once stored), its poses up to
        ``last_seq`` and the skill instance it began on (the store checks it again:
        :class:`..errors.SkillReplaced`), or None after answering the error."""
        last_seq = body.get("last_seq")
        if isinstance(last_seq, int) and st.capture_kind in kinds and st.capture is not None:
            _wait_for_pose(st, last_seq)
        with st.lock:
            capture = st.capture if st.capture_kind in kinds else None
            started_on = st.capture_instance
            poses = None if capture is None else list(capture)
        if capture is None or poses is None:
            reply_error(query, "conflict", f"no {what} is being captured on this stream",
                         what.split()[0])
            return None
        try:
            self._check_skill(st.skill, started_on, what)
        except ServiceError as exc:
            _end(st, capture)
            reply_error(query, error_type(exc), exc.message, exc.field)
            return None
        if isinstance(last_seq, int):
            poses = [p for p in poses if p.seq <= last_seq]
        return capture, poses, _began_on(started_on)

    def _check_skill(self, skill: str, started_on: str | None, what: str) -> None:
        """SkillReplaced when the skill a capture began on is no longer under its name,
        deleted or deleted and created again: both are the same fact to the person, and a
        plain "not found" would not say the capture is what was lost."""
        if started_on is None:  # a steered run begun on no skill: the store names it
            return
        now = self.skill_instance(skill)
        if now != started_on:
            raise SkillReplaced(skill, what.split()[0], exists=now is not None)

    def _demo_stop(self, query: Any, st: Stream, body: dict[str, Any]) -> None:
        label = st.capture_label
        captured = self._capture_stop(query, st, body, _STOP_KINDS["demo", "stop"],
                                     "demonstration")
        if captured is None:
            return
        capture, poses, instance = captured
        last_seq = body.get("last_seq")
        if capture.over_until(last_seq):
            # as REST refuses such a demonstration (413); and it can never be stored, its
            # poses past the limit not held: the capture is over
            _end(st, capture)
            reply_error(query, "payload_too_large",
                        f"expected a demonstration of at most {capture.cap} poses (limit "
                        f"CANAL_UPLOAD_MAX_POINTS, as an upload), got {capture.came} "
                        "captured; the capture is over: start again and stop within the limit, "
                        "or stop with a last_seq before the pose "
                        f"{capture.over_from} where it was reached", "positions")
            return
        try:
            created = self._store_demo(st.skill, poses, instance, label)
        except ServiceError as exc:
            if _ends_capture(exc):
                _end(st, capture)
            reply_error(query, error_type(exc), exc.message, exc.field)
            return
        _end(st, capture)
        query.reply(query.key_expr, orjson.dumps(created), encoding=ENC_JSON)

    def _correction_start(self, query: Any, st: Stream, body: dict[str, Any]) -> None:
        weight = body.get("weight")
        self._capture_start(query, st, body, str(body["kind"]),
                            1.0 if weight is None else float(weight))

    def _correction_stop(self, query: Any, st: Stream, body: dict[str, Any]) -> None:
        kind, weight, label = st.capture_kind, st.capture_weight, st.capture_label
        captured = self._capture_stop(query, st, body, _STOP_KINDS["correction", "stop"],
                                     "correction")
        if captured is None:
            return
        capture, poses, instance = captured
        # a stream's correction refines the route it follows
        if self._store_correction(query, st, str(kind), poses, instance, weight, label,
                                  self.route_of(st), capture.over_until(body.get("last_seq")),
                                  capture.cap):
            _end(st, capture)

    def _steer_keep(self, query: Any, st: Stream, body: dict[str, Any]) -> None:
        """Keep the stream's steered run in progress (else its last one) as an include of
        the route it was steered on."""
        poses: list[Any] | None
        with st.lock:
            in_progress = st.capture_kind == "steer" and bool(st.capture)
            if in_progress:
                run, started_on, run_id = st.capture, st.capture_instance, st.capture_run
                route, serial = st.route, st.route_serial
            else:
                run, started_on, run_id = st.steered, st.steered_instance, st.steered_run
                route, serial = st.steered_route, st.steered_serial
            poses = list(run) if run else None
        if not run or not poses:
            reply_error(query, "conflict", "this stream has no steered run to keep", "steer")
            return
        try:
            self._check_skill(st.skill, started_on, "correction")
        except ServiceError as exc:
            reply_error(query, error_type(exc), exc.message, exc.field)
            done = True  # the run is gone with its skill
        else:
            weight, label = body.get("weight"), body.get("label")
            done = self._store_correction(query, st, "include", poses, _began_on(started_on),
                                          1.0 if weight is None else float(weight),
                                          "steered" if label is None else label,
                                          self._steered_route(st, poses, route, serial),
                                          run.over, run.cap)
        if done:
            with st.lock:
                # the run may have ended while it was stored (0.5 s after the last input):
                # its end moved it to the last-run slot, where a second keep would store it
                # again; it goes wherever it is now
                if st.capture_kind == "steer" and st.capture_run == run_id:
                    st.capture, st.capture_kind, st.steer = None, None, None
                if st.steered_run == run_id:
                    st.steered = None

    def _steered_route(self, st: Stream, poses: list[Any] | None, route: int | None,
                       serial: int) -> int | None:
        """The route, in the skill's model now, of a steered run steered on ``route`` of the
        model entry ``serial``: that route, or, when another model version came since (a fit
        numbers its routes afresh), the route its poses lie along, as a refit places a kept
        correction (None: one route, or the canal of all)."""
        entry = self.models.entry(st.skill)
        if entry.status != "ok" or entry.routes is None or not poses or route is None:
            return None  # the canal of all: every route's canal the poses pass through
        if serial == entry.serial and route < len(entry.routes):
            return route
        points = [p.position for p in poses if len(p.position) == entry.dim]
        if not points:
            return None
        return way_of(entry.chooser, points, route if route < len(entry.routes) else None)

    def _store_correction(self, query: Any, st: Stream, kind: str, poses: list[Any],
                          instance: str, weight: float, label: str | None,
                          route: int | None, over: int = 0, cap: int = 0) -> bool:
        """Apply the poses as a correction of ``route`` and answer; False when refused in a
        way that leaves the capture open (:func:`_ends_capture`). ``over``: the poses past
        the capture's ``cap`` that were not held."""
        far = 0
        try:
            poses = poses_of_dim(poses, self.service.skill_dim(st.skill), "samples")
            captured = len(poses)
            poses = self._within_reach(st, poses, route)
            far = captured - len(poses)
            held = len(poses)
            poses = thinned(poses, MAX_CORRECTION_SAMPLES)
            body = CorrectionIn.model_validate({
                "kind": kind, "samples": [list(p.position) for p in poses],
                "timestamps": capture_times(poses),
                "weight": weight, "label": label or "",
                "plan": self._live_plan(st, poses, route) if kind == "exclude" else None,
                "route": route})
            made = self.service.correct(st.skill, body, instance=instance)
            if far:
                made.notes = [*made.notes, f"{far} of the {captured} captured poses "
                              f"{'was' if far == 1 else 'were'} left out, beyond the canal's "
                              f"reach (more than {bounds.MAX_REACH:g} canal sizes from it)"]
            if len(poses) < held:
                made.notes = [*made.notes, f"{held} captured poses thinned to {len(poses)}, "
                              "evenly, the first and last kept: a correction holds at most "
                              f"{MAX_CORRECTION_SAMPLES} samples"]
            if over:
                made.notes = [*made.notes, f"{over} captured poses after the first {cap} were "
                              f"not held (a capture holds at most {cap} poses): the correction "
                              "ends where that limit was reached"]
        except ValidationError as exc:
            first = pydantic_detail(exc.errors(include_url=False)[0])
            reply_error(query, "invalid_input", first["message"], first["field"])
            return False
        except ServiceError as exc:
            reply_error(query, error_type(exc), exc.message, exc.field)
            return _ends_capture(exc)
        query.reply(query.key_expr, orjson.dumps(made.model_dump(mode="json")), encoding=ENC_JSON)
        return True

    def _followed_canal(self, st: Stream, route: int | None) -> Any:
        """The canal a correction from the stream refines (``route``'s, in a model of several
        routes); None when the skill has no model here."""
        entry = self.models.entry(st.skill)
        if entry.status != "ok" or entry.canal is None:
            return None
        if route is None or entry.routes is None or route >= len(entry.routes):
            return entry.canal
        return entry.routes[route].canal

    def _within_reach(self, st: Stream, poses: list[Any], route: int | None) -> list[Any]:
        """The captured poses within the reach a correction's samples are held to (a
        sensor spike a billion metres out is a finite pose the tracker answered
        ``outside_canal``): one such pose must not cost the person the whole push."""
        canal = self._followed_canal(st, route)
        if canal is None:
            return poses  # the service answers for the model
        centre, size = bounds.canal_extent(canal.directrix, canal.radii)
        reach = bounds.MAX_REACH * size
        kept = [p for p in poses
                if float(np.linalg.norm(np.asarray(p.position, dtype=np.float64) - centre)) <= reach]
        return kept if kept else poses  # none left: the service says what came

    def _live_plan(self, st: Stream, poses: list[Any], route: int | None
                   ) -> list[list[float]] | None:
        """What the robot was on before the push: the live tracker keeps its ratio from the
        first captured pose on (the paper's constant ratio, no end decay), in the canal of
        the route the stream follows."""
        canal = self._followed_canal(st, route)
        if canal is None or not poses or len(poses[0].position) != canal.dim:
            return None
        try:
            plan = canal.reproduce_detailed(
                np.array(poses[0].position, dtype=np.float64), persistence="constant",
                entry=0.0, end_decay=0.0)
        except Exception:  # a start no section brackets: the service's default plan
            return None
        return plan.positions.tolist()  # type: ignore[no-any-return]

    def skill_instance(self, skill: str) -> str | None:
        """The skill now under the name (:func:`..storage.repository.skill_instance`), None
        when there is none."""
        with self.service.db.read() as s:
            return repo.skill_instances(s, skill).get(skill)

    def _store_demo(self, skill: str, poses: list[Any], instance: str,
                    label: str | None) -> dict[str, Any]:
        dim = self.service.skill_dim(skill)
        poses = poses_of_dim(poses, dim, "positions")
        positions = [p.position for p in poses]
        quats = [p.orientation for p in poses]
        demo = check_demonstration(
            positions, dim, capture_times(poses),
            quats if poses and all(q is not None for q in quats) else None)
        created = self.service.add_demonstration(skill, demo, label, "zenoh", instance=instance)
        return created.model_dump(mode="json")  # type: ignore[no-any-return]


def _wait_for_pose(st: Stream, seq: int) -> None:
    """Wait until the worker has seen the pose ``seq`` (the last one the robot sent before
    its stop), for at most ``_STOP_WAIT_S``, and no longer once the stream's poses stop
    coming. Only a ``seq`` at most ``_IN_FLIGHT`` poses ahead is waited for: this runs on
    the thread that answers every stream's queries, and a ``seq`` no pose will reach must not
    hold the other robots' queries up."""
    if not 0 < seq - st.last_seq <= _IN_FLIGHT:
        return
    now = time.monotonic()
    deadline, seen, moved = now + _STOP_WAIT_S, st.last_seq, now
    while st.last_seq < seq and now < deadline and now - moved < _STALL_S:
        time.sleep(0.001)
        now = time.monotonic()
        if st.last_seq != seen:
            seen, moved = st.last_seq, now


def thinned(poses: list[Any], most: int) -> list[Any]:
    """At most ``most`` of the poses, evenly spaced, the first and the last kept (a
    correction is a shape: a run held at a lower rate is the same run)."""
    n = len(poses)
    if n <= most:
        return poses
    picks = np.floor(np.linspace(0.0, n - 1, most) + 0.5).astype(np.int64)
    return [poses[int(i)] for i in picks]


def poses_of_dim(poses: list[Any], dim: int, field: str) -> list[Any]:
    """The captured poses with the skill's ``dim`` coordinates. The others were answered
    ``wrong_dimension`` as they came and never tracked: a glitch does not cost the person the
    whole capture. InvalidInput on ``field`` when none is left."""
    kept = [p for p in poses if len(p.position) == dim]
    if kept:
        return kept
    if not poses:
        raise InvalidInput(f"expected {field} captured between start and stop, got no pose",
                           field=field)
    dims = " or ".join(map(str, sorted({len(p.position) for p in poses})))
    raise InvalidInput(f"expected {field} with {dim} coordinates for this {dim}-D skill, got "
                       f"{len(poses)} poses with {dims}", field=field)


def capture_times(poses: list[Any]) -> list[float] | None:
    """The captured poses' times, or None (stored untimed) unless every pose has one. A
    capture whose every time is 0 carries none either: a ROS 2 PoseStamped's header stamp
    left unset is 0, and refusing its demonstration for times that do not advance would
    lose it for a field the robot never meant to send."""
    times = [p.t for p in poses]
    if not poses or any(t is None for t in times) or all(t == 0 for t in times):
        return None
    return times


def _ends_capture(exc: ServiceError) -> bool:
    """A stop refused with ``exc`` ends its capture: only when the skill it began on is
    gone (nothing could store it); any other refusal leaves it open to stop again."""
    return isinstance(exc, SkillReplaced) or (error_type(exc) == "not_found"
                                              and exc.field == "skill")


def _end(st: Stream, capture: Capture) -> None:
    """End the stream's capture ``capture`` (stored, or its skill gone), unless a start
    over has replaced it meanwhile."""
    with st.lock:
        if st.capture is capture:
            st.capture, st.capture_kind = None, None


def _began_on(instance: str | None) -> str:
    """The skill instance a capture began on, for the store to check; a steered run begun
    while no skill had the name matches none."""
    return "" if instance is None else instance


def reply_error(query: Any, key: str, message: str, field: str | None = None) -> None:
    """Answer a live query with an error: its type, the field it names, the message."""
    body = {"error": {"type": key, "field": field, "message": message}}
    try:
        query.reply_err(orjson.dumps(body), encoding=ENC_JSON)
    except Exception:
        log.exception("could not answer a live query")


__all__ = ["Captures", "capture_times", "poses_of_dim", "reply_error"]
