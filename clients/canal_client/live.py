"""Robot side of the live protocol: stream poses to Canal's Zenoh bridge, get targets back.

.. code-block:: python

    from canal_client.live import PoseStreamer

    with PoseStreamer("pour", robot="arm1", endpoint="tcp/127.0.0.1:7447") as ps:
        seq = ps.send([0.0, 0.02, 0.0], restart=True)
        answer = ps.wait_for(seq, timeout=0.1)      # a wire.Target
        if answer is not None and answer.usable:
            move_to(answer.target)

Targets arrive on a Zenoh FIFO channel and are read by the streamer's own thread (Zenoh's
callback threads never run user code); ``on_target`` is called from that thread.
"""

from __future__ import annotations

import atexit
import math
import re
import threading
import time
import weakref
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import orjson
import zenoh

from canal_protocol import codecs, wire
from canal_protocol import keys as keyspace
from canal_protocol.credentials import insert_credentials

from .errors import ArgumentError, CanalClientError

_ENC_JSON = zenoh.Encoding.APPLICATION_JSON
_ENC_BINARY = zenoh.Encoding.APPLICATION_OCTET_STREAM


class LiveError(CanalClientError, RuntimeError):
    """The bridge could not be reached or refused a request; ``body`` is its JSON error."""

    def __init__(self, message: str, body: Any = None) -> None:
        super().__init__(message)
        self.body = body


class NoBridgeError(LiveError):
    """No Canal bridge subscribes to the stream's pose key. ``reached``: whether the session
    reached any Zenoh node; when not, nothing listens at the endpoint or it refused the
    session (a service started with ``--token`` admits only sessions given that token)."""

    def __init__(self, message: str, reached: bool) -> None:
        super().__init__(message)
        self.reached = reached


def zenoh_reason(exc: BaseException) -> str:
    """A Zenoh error as one line: its message, where a JSON5 parse stopped, without the Rust
    source location zenoh appends (``... at /root/.cargo/.../lib.rs:1486.``)."""
    text = re.sub(r"\s+at \S+\.rs:\d+\.?\s*$", "", str(exc).strip())
    quoted = re.search(r'msg: "(.*?)(?:\s+at \S+\.rs:\d+\.?)?"', text)
    if quoted:  # Json5Err(Message { msg: "...", location: ... })
        text = quoted[1]
    place = re.match(r"\s*-->\s*(\d+):(\d+)", text)
    said = re.search(r"^\s*=\s*(.+)$", text, re.MULTILINE)
    if place and said:  # a parse error drawn as a caret under the line
        text = f"line {place[1]}, column {place[2]}: {said[1]}"
    return " ".join(text.split())


ENDPOINT_FORM = "Zenoh endpoints like tcp/127.0.0.1:7447 (<protocol>/<address>, comma-separated)"


def client_config(endpoint: str | Sequence[str] = "tcp/127.0.0.1:7447",
                  zenoh_config: str | Path | None = None,
                  token: str | None = None) -> zenoh.Config:
    """A peer config connecting to ``endpoint`` with multicast scouting off, or the user's
    Zenoh JSON5 file unchanged. ``token``: the service's bearer token, which a service
    started with ``--token`` requires on its live path too (as Zenoh credentials,
    :mod:`canal_protocol.credentials`; not used with a config file, which says its own).

    Raises :class:`~canal_client.errors.ArgumentError` (argument ``endpoint`` or
    ``zenoh_config``) for an endpoint Zenoh cannot parse, and for a config file that does not
    exist or that Zenoh refuses."""
    if zenoh_config is not None:
        path = Path(zenoh_config)
        expected = "a Zenoh JSON5 config file"
        if not path.exists():
            raise ArgumentError("zenoh_config", expected, f"{str(path)!r}, which does not exist")
        if not path.is_file():
            raise ArgumentError("zenoh_config", expected, f"{str(path)!r}, which is not a file")
        try:
            return zenoh.Config.from_file(str(path))
        except zenoh.ZError as exc:
            raise ArgumentError("zenoh_config", expected,
                                f"{str(path)!r}: {zenoh_reason(exc)}") from None
    endpoints = [endpoint] if isinstance(endpoint, str) else list(endpoint)
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("listen/endpoints", "[]")
    for one in endpoints or [""]:  # each alone, to name the one refused
        ok = isinstance(one, str) and bool(one.strip())
        if ok:
            try:
                config.insert_json5("connect/endpoints", orjson.dumps([one]).decode())
            except zenoh.ZError:
                ok = False
        if not ok:
            raise ArgumentError("endpoint", ENDPOINT_FORM, repr(one))
    config.insert_json5("connect/endpoints", orjson.dumps(endpoints).decode())
    if token:
        insert_credentials(config, token)
    return config


def _matching(publisher: Any) -> bool:
    """Whether a subscriber matches ``publisher``. zenoh-python answers a MatchingStatus
    object, always true itself, whose ``matching`` says (its stub says bool)."""
    status = publisher.matching_status
    return bool(getattr(status, "matching", status))


def _reached(session: Any) -> bool:
    """Whether the session is connected to any Zenoh peer or router."""
    return bool(list(session.info.peers_zid()) or list(session.info.routers_zid()))


def _reply_body(reply: Any) -> tuple[bool, Any]:
    ok = reply.ok
    if ok is not None:
        return True, orjson.loads(ok.payload.to_bytes())
    err = reply.err
    try:
        return False, orjson.loads(err.payload.to_bytes())
    except Exception:
        return False, {"error": {"type": "unknown", "message": err.payload.to_string()}}


def _check_finite(value: Any, where: str) -> None:
    if isinstance(value, float) and not math.isfinite(value):
        raise ArgumentError(where or "the body", "a finite number", str(value))
    if isinstance(value, dict):
        for name, item in value.items():
            _check_finite(item, f"{where}.{name}" if where else str(name))
    elif isinstance(value, list | tuple):
        for i, item in enumerate(value):
            _check_finite(item, f"{where}[{i}]")


def query_json(session: Any, key: str, body: Any = None, timeout: float = 5.0) -> Any:
    """One Zenoh query answered with JSON; LiveError on an error reply or no reply.

    Raises ValueError, before anything is sent, when ``body`` holds NaN or infinity: JSON
    has neither, and orjson would send null, which the bridge reads as "the default".
    """
    if body is not None:
        _check_finite(body, "")
    payload = None if body is None else orjson.dumps(body)
    replies = session.get(key, payload=payload, encoding=_ENC_JSON if payload else None,
                          timeout=timeout)
    for reply in replies:
        ok, data = _reply_body(reply)
        if ok:
            return data
        err = data.get("error", {}) if isinstance(data, dict) else {}
        raise LiveError(f"{key}: {err.get('type')}: {err.get('message')}", data)
    raise LiveError(f"{key}: no answer within {timeout} s (is the bridge running?)")


class PoseStreamer:
    """One robot's pose stream for one skill.

    Parameters
    ----------
    skill, robot : str
        Key chunks of the stream (``{prefix}/{skill}/{robot}/pose``).
    endpoint : str or list of str
        Where the bridge listens (ignored when ``zenoh_config`` is given).
    zenoh_config : path, optional
        A standard Zenoh JSON5 config file, used unchanged (routers, TLS, ACL).
    prefix : str
    encoding : "binary" | "json"
    on_target : callable, optional
        Called with every :class:`~canal_protocol.wire.Target`, from the streamer's thread.
    session : zenoh.Session, optional
        Use this session instead of opening one (it is not closed by :meth:`close`).
    connect_timeout : float
        How long to wait for the bridge's pose subscriber to be reachable.
    token : str, optional
        The service's bearer token, when it has one (see :func:`client_config`).
    """

    def __init__(self, skill: str, robot: str = "robot", *,
                 endpoint: str | Sequence[str] = "tcp/127.0.0.1:7447",
                 zenoh_config: str | Path | None = None, prefix: str = "canal",
                 encoding: str = "binary",
                 on_target: Callable[[wire.Target], None] | None = None,
                 session: Any = None, connect_timeout: float = 5.0,
                 token: str | None = None) -> None:
        if encoding not in ("binary", "json"):
            raise ArgumentError("encoding", "'binary' or 'json'", repr(encoding))
        self.keys = keyspace.keys(skill, robot, prefix)
        self.encoding = encoding
        self.on_target = on_target
        self._own_session = session is None
        if session is None:
            config = client_config(endpoint, zenoh_config, token)
            try:
                session = zenoh.open(config)
            except zenoh.ZError as exc:  # no router answers, a protocol zenoh does not have
                raise LiveError(f"cannot open a Zenoh session: {zenoh_reason(exc)}") from None
        self.session = session
        self._cond = threading.Condition()
        self._latest: wire.Target | None = None
        self._answers: dict[int, wire.Target] = {}
        self._seq = 0
        self._raw = False  # after send_raw, answers to seqs we did not number are ours too
        self._closed = False
        self._thread: threading.Thread | None = None
        try:
            self._sub = self.session.declare_subscriber(self.keys.target,
                                                        zenoh.handlers.FifoChannel(1024))
            self._pub = self.session.declare_publisher(
                self.keys.pose, encoding=_ENC_JSON if encoding == "json" else _ENC_BINARY,
                express=False, congestion_control=zenoh.CongestionControl.BLOCK)
            deadline = time.monotonic() + connect_timeout
            while not _matching(self._pub):
                if time.monotonic() > deadline:
                    reached = _reached(self.session)
                    raise NoBridgeError(
                        f"no Canal bridge subscribes to {self.keys.pose} (waited "
                        f"{connect_timeout:g} s)" + ("" if reached else (
                            ": no Zenoh node accepted this session (none listens at the "
                            "endpoint, or it refused the session's credentials: a service "
                            "started with --token admits only sessions given that token)")),
                        reached)
                time.sleep(0.005)
            self._thread = threading.Thread(target=self._receive, name="canal-pose-streamer",
                                            daemon=True)
            self._thread.start()
            _OPEN.add(self)
        except BaseException:
            self.close()
            raise

    # ---- poses and targets ------------------------------------------------------------------

    def send(self, position: Sequence[float], orientation: Sequence[float] | None = None,
             t: float | None = None, *, restart: bool = False) -> int:
        """Publish a pose; returns its seq (answered by the target with the same seq)."""
        seq = self._seq
        self._seq += 1
        if self.encoding == "json":
            self._pub.put(wire.encode_pose_json(seq, position, orientation, t, restart))
        else:
            self._pub.put(wire.encode_pose(seq, position, orientation, t, restart))
        return seq

    def send_raw(self, payload: bytes, *, json: bool = False) -> None:
        """Publish bytes as they are (for tests of malformed input). From then on, answers
        to any seq are accepted (the streamer no longer knows which seqs it sent)."""
        self._raw = True
        self._pub.put(payload, encoding=_ENC_JSON if json else _ENC_BINARY)

    @property
    def next_seq(self) -> int:
        """The seq the next :meth:`send` will use."""
        return self._seq

    def latest(self) -> wire.Target | None:
        """The most recent target received, or None."""
        return self._latest

    def wait_for(self, seq: int, timeout: float = 1.0) -> wire.Target | None:
        """The target answering ``seq`` (or a later one, if the bridge coalesced), or None
        after ``timeout`` seconds."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                answer = self._answers.pop(seq, None)
                if answer is not None:
                    return answer
                latest = self._latest
                if latest is not None and latest.seq is not None and latest.seq > seq:
                    return latest
                left = deadline - time.monotonic()
                if left <= 0 or self._closed:
                    return None
                self._cond.wait(left)

    def _receive(self) -> None:
        recv = self._sub.handler.recv
        while True:
            try:
                sample = recv()
            except Exception:
                return
            try:
                answer = wire.decode_target_by_encoding(str(sample.encoding),
                                                        sample.payload.to_bytes())
            except wire.WireError:
                continue
            # Only answers to a seq this streamer has sent count: a stranger's high-seq pose
            # on our key (possible only on an open Zenoh network; see docs/live.md) must not
            # become "the latest" and shadow the real answers.
            if answer.seq is not None and answer.seq >= self._seq and not self._raw:
                continue
            with self._cond:
                self._latest = answer
                if answer.seq is not None:
                    self._answers[answer.seq] = answer
                    if len(self._answers) > 256:  # nobody waits for old answers
                        for k in sorted(self._answers)[:128]:
                            del self._answers[k]
                self._cond.notify_all()
            if self.on_target is not None:
                self.on_target(answer)

    # ---- model and demonstrations -----------------------------------------------------------

    def model(self, timeout: float = 5.0) -> dict[str, Any]:
        """The skill's latest model (the REST body of ``models/latest?serialized=true``)."""
        return query_json(self.session, self.keys.model, timeout=timeout)  # type: ignore[no-any-return]

    def start_demo(self, label: str | None = None, timeout: float = 5.0) -> dict[str, Any]:
        """Begin capturing this stream's poses, from the next :meth:`send` on: ``{"capturing",
        "from_seq", "discarded"}``. During a demonstration's capture it starts over, and
        ``discarded`` is the number of poses thrown away."""
        return query_json(self.session, self.keys.demo_start,  # type: ignore[no-any-return]
                          {"from_seq": self._seq, "label": label}, timeout)

    def stop_demo(self, timeout: float = 10.0) -> dict[str, Any]:
        """Store the captured poses as a new demonstration: ``{"id", "n_points", "checksum"}``."""
        return query_json(self.session, self.keys.demo_stop,  # type: ignore[no-any-return]
                          self._last_seq(), timeout)

    def _last_seq(self) -> dict[str, int]:
        """The stop queries' body: the last seq sent (nothing when no pose was sent yet)."""
        return {"last_seq": self._seq - 1} if self._seq > 0 else {}

    # ---- corrections and steering -----------------------------------------------------------

    def start_correction(self, kind: str = "exclude", *, weight: float = 1.0,
                         label: str | None = None, timeout: float = 5.0) -> dict[str, Any]:
        """Begin capturing this stream's poses as a correction of ``kind`` ("include": this
        path is right too; "exclude": the robot is being pushed away from where it went),
        from the next :meth:`send` on."""
        return query_json(self.session, self.keys.correction_start,  # type: ignore[no-any-return]
                          {"kind": kind, "weight": weight, "from_seq": self._seq,
                           "label": label}, timeout)

    def stop_correction(self, timeout: float = 10.0) -> dict[str, Any]:
        """Apply the captured poses as a correction: the reply is the new model version (the
        REST answer of ``POST /skills/{name}/corrections``); every bridge serves it soon
        after, and streams in flight switch at the section they reached."""
        return query_json(self.session, self.keys.correction_stop,  # type: ignore[no-any-return]
                          self._last_seq(), timeout)

    def steer(self, u: float, v: float) -> None:
        """A person's 2-D input, u (left +) and v (up +) in [-1, 1]: the plan moves across
        the section while the canal carries the robot along. Send it at the input device's
        rate; with no input for half a second the stream is back on the plain ratio rule."""
        pub = getattr(self, "_steer_pub", None)
        if pub is None:
            pub = self._steer_pub = self.session.declare_publisher(
                self.keys.steer, encoding=_ENC_JSON if self.encoding == "json" else _ENC_BINARY)
        if self.encoding == "json":
            pub.put(codecs.encode_steer_json(u, v))
        else:
            pub.put(codecs.encode_steer(u, v, self._seq))

    def keep_steered(self, label: str | None = None, weight: float = 1.0,
                     timeout: float = 10.0) -> dict[str, Any]:
        """Keep the last steered run (or the one in progress) as an include correction: the
        reply is the new model version."""
        return query_json(self.session, self.keys.steer_keep,  # type: ignore[no-any-return]
                          {"label": label, "weight": weight}, timeout)

    # ---- lifecycle --------------------------------------------------------------------------

    def close(self) -> None:
        """Undeclare everything and close the session if this streamer opened it."""
        if self._closed:
            return
        self._closed = True
        _OPEN.discard(self)
        with self._cond:
            self._cond.notify_all()
        for name in ("_sub", "_pub", "_steer_pub"):
            entity = getattr(self, name, None)
            if entity is not None:
                try:
                    entity.undeclare()
                except Exception:
                    pass
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        if self._own_session:
            self.session.close()

    def __enter__(self) -> PoseStreamer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


#: Streamers not closed yet: closed at exit. A receiving thread still blocked in Zenoh when
#: the interpreter tears down aborts the process (SIGABRT, "exception not rethrown"): a
#: robot program that never reached close() would end with a crash.
_OPEN: weakref.WeakSet[PoseStreamer] = weakref.WeakSet()


@atexit.register
def _close_open_streamers() -> None:
    for streamer in list(_OPEN):
        try:
            streamer.close()
        except Exception:
            pass


__all__ = ["LiveError", "NoBridgeError", "PoseStreamer", "client_config", "query_json"]
