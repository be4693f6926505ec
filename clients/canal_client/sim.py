"""A simulated robot for the live bridge: start anywhere, chase Canal's targets, get pushed.

``run_sim("pour")`` opens a :class:`~canal_client.live.PoseStreamer`, picks a random start
inside the canal (from the model queryable) unless given one, and then at ``rate_hz``:
publishes its position, waits for the target answering it (or keeps the latest one), and
moves toward the target with a first-order lag (``x += min(gain * dt, 1) * (target - x)``)
or a critically damped PD lag (``a = gain * (target - x) - 2 * sqrt(gain) * v``). A push
displaces the robot instantly by an offset, at a time (seconds since start, a number) or at a
progress (a string like ``"50%"``). It stops when Canal says ``done`` or after ``timeout_s``.

``keep_out=(centre, radius)``: a simulated person who knows of a keep-out sphere the canal
does not. When the robot comes within ``KEEP_OUT_APPROACH`` radii of it, the person starts a
correction (``correction/start``, exclude); while the robot is inside the sphere they hold
it on its surface; once it is past (or done), ``correction/stop`` turns the pushed run into
an exclude correction, and the next runs keep out of the sphere on their own.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from canal_protocol import wire

from .errors import CanalClientError
from .live import LiveError, PoseStreamer

Push = tuple[float | str, Sequence[float]]
#: The simulated person starts a correction this many radii from the keep-out centre.
KEEP_OUT_APPROACH = 1.5


@dataclass
class PushRecord:
    """One push that happened: when, by how much, and what the bridge said next."""

    when: float | str  # as asked: seconds, or progress ("50%", "0.5")
    offset: list[float]
    at_s: float  # seconds into the run when it was applied
    progress: float  # the canal progress reached just before it
    inside_after: bool | None = None  # the first answer after it: inside (or done)?
    back_inside_s: float | None = None  # when it left the canal: seconds until back inside


@dataclass
class SimResult:
    """What happened in one simulated run."""

    reached_end: bool
    all_inside: bool
    n_steps: int
    positions: np.ndarray  # (n_steps, D): every pose sent
    targets: list[wire.Target]  # the answer used at each step (None-free: missing answers skipped)
    inside: np.ndarray  # bool: the bridge's inside (or done) flag per answered pose, but
    # restart_pending (it says nothing of where the robot is)
    min_eta: float
    max_eta: float
    duration: float
    start: np.ndarray
    model_version: int | None = None
    statuses: dict[str, int] = field(default_factory=dict)
    missed: int = 0  # poses whose answer did not arrive in time
    pushes_done: int = 0
    # Pushes still pending when the run ended (their time or progress was never reached).
    pushes_pending: list[tuple[float | str, list[float]]] = field(default_factory=list)
    seed: int | None = None
    pushes: list[PushRecord] = field(default_factory=list)  # the ones applied, in order
    #: keep-out runs: steps the person held the robot out of the sphere, the model versions
    #: their corrections made, and why a correction was refused (when one was)
    held: int = 0
    corrections: list[int] = field(default_factory=list)
    refused: list[str] = field(default_factory=list)


class _Person:
    """The simulated person of ``run_sim(keep_out=...)``."""

    def __init__(self, ps: PoseStreamer, centre: Sequence[float], radius: float) -> None:
        self.ps = ps
        self.centre = np.asarray(centre, dtype=np.float64)
        self.radius = float(radius)
        self.capturing = False
        self.pushed = False
        self.held = 0
        self.versions: list[int] = []
        self.refused: list[str] = []

    def act(self, x: np.ndarray) -> np.ndarray:
        """The position after the person's hand: on the sphere's surface when inside it."""
        away = x - self.centre
        distance = float(np.linalg.norm(away))
        if not self.capturing and distance < KEEP_OUT_APPROACH * self.radius:
            self.ps.start_correction("exclude", label="keep-out")
            self.capturing, self.pushed = True, False
        if distance < self.radius:
            self.held += 1
            self.pushed = True
            direction = away / distance if distance > 0.0 else np.eye(x.shape[0])[-1]
            return np.asarray(self.centre + 1.01 * self.radius * direction)
        if self.capturing and self.pushed and distance > KEEP_OUT_APPROACH * self.radius:
            self.finish()
        return x

    def finish(self) -> None:
        """Stop the capture: an exclude correction when the robot was pushed."""
        if not self.capturing:
            return
        self.capturing = False
        try:
            made = self.ps.stop_correction()
            self.versions.append(int(made["version"]))
        except LiveError as exc:
            if self.pushed:
                self.refused.append(str(exc))


def random_interior_start(model: dict[str, Any], rng: np.random.Generator,
                          max_fraction: float = 0.6) -> np.ndarray:
    """A random point well inside the canal, in its first ``max_fraction`` of sections."""
    import canal_core

    canal = canal_core.routes.routes_from_dict(model["serialized"]).pooled
    n = canal.n_sections
    normals = canal.normals
    assert normals is not None  # every fitted canal has its frames
    for _ in range(200):
        i = int(rng.integers(0, max(int(max_fraction * (n - 1)), 1)))
        if canal.dim == 3:
            angle = rng.uniform(0.0, 2.0 * math.pi)
            binormals = canal.binormals
            assert binormals is not None  # 3-D canals have both
            direction = math.cos(angle) * normals[i] + math.sin(angle) * binormals[i]
        else:
            direction = normals[i] * rng.choice([-1.0, 1.0])
        point = canal.directrix[i] + rng.uniform(0.0, 0.6) * canal.radii[i] * direction
        if bool(canal.contains(point[None, :])[0]):
            return np.asarray(point, dtype=np.float64)
    return np.asarray(canal.directrix[0], dtype=np.float64)


def _push_due(when: float | str, elapsed: float, progress: float) -> bool:
    if isinstance(when, str):
        text = when.strip()
        value = float(text[:-1]) / 100.0 if text.endswith("%") else float(text)
        return progress >= value
    return elapsed >= float(when)


def describe_push(push: PushRecord) -> str:
    """What one push did, in a line (for the CLI and logs)."""
    shown = ",".join(f"{v:g}" for v in push.offset)
    head = f"push ({shown}) applied at {push.at_s:.2f} s, progress {push.progress:.0%}"
    if push.inside_after is None:
        return f"{head}: no answer came after it"
    if push.inside_after:
        return f"{head}: still inside the canal"
    if push.back_inside_s is None:
        return f"{head}: out of the canal, not back inside before the run ended"
    return f"{head}: out of the canal, back inside {push.back_inside_s:.2f} s later"


def describe_pending(result: SimResult) -> list[str]:
    """One line per push that never happened, saying why (for the CLI and logs)."""
    lines = []
    for when, offset in result.pushes_pending:
        shown = ",".join(f"{v:g}" for v in offset)
        at = f"progress {when}" if isinstance(when, str) else f"{float(when):g} s"
        lines.append(f"push {at}:{shown} not applied: the run ended after "
                     f"{result.duration:.2f} s at progress {_last_progress(result):.0%}; "
                     f"push earlier (e.g. --push 0.2:{shown}) or by progress "
                     f"(--push 50%:{shown})")
    return lines


def _last_progress(result: SimResult) -> float:
    return float(result.targets[-1].progress) if result.targets else 0.0


class SimInputError(CanalClientError, ValueError):
    """An argument of :func:`run_sim` that cannot drive a robot (on this skill); ``param``
    names it."""

    def __init__(self, param: str, message: str) -> None:
        super().__init__(message)
        self.param = param


def _check_positive(param: str, value: float, what: str) -> None:
    if not (math.isfinite(value) and value > 0):
        raise SimInputError(param, f"expected {what} > 0 (a finite number), got {value:g}")


def check_run(rate_hz: float = 100.0, timeout_s: float = 60.0, gain: float | None = None) -> None:
    """Raise :class:`SimInputError` for a rate, timeout or gain that cannot drive a robot
    (each finite and > 0)."""
    _check_positive("rate_hz", rate_hz, "a rate")
    _check_positive("timeout_s", timeout_s, "a timeout")
    if gain is not None:
        _check_positive("gain", gain, "a gain")


def check_points(dim: int, start: ArrayLike | None = None,
                 pushes: Sequence[tuple[float | str, ArrayLike]] = (),
                 keep_out: tuple[ArrayLike, float] | None = None) -> None:
    """Raise :class:`SimInputError` unless the start, every push offset and the keep-out
    centre have ``dim`` coordinates (numpy would broadcast them or fail mid-run)."""
    shown = ("start", start), *(("pushes", offset) for _, offset in pushes), \
        ("keep_out", None if keep_out is None else keep_out[0])
    for param, value in shown:
        if value is not None and np.size(value) != dim:
            raise SimInputError(param, f"expected {dim} coordinates (the skill is {dim}-D), "
                                       f"got {np.size(value)}")


#: The longest wait for the bridge, and then for the model, before a run.
CONNECT_WAIT_S = 5.0


def run_sim(skill: str, *, robot: str = "sim", start: Sequence[float] | None = None,
            rate_hz: float = 100.0, lag: str = "first-order", gain: float | None = None,
            pushes: Sequence[Push] = (), timeout_s: float = 60.0,
            endpoint: str | Sequence[str] = "tcp/127.0.0.1:7447",
            zenoh_config: str | Path | None = None, prefix: str = "canal",
            encoding: str = "binary", seed: int | None = None,
            session: Any = None, token: str | None = None,
            keep_out: tuple[Sequence[float], float] | None = None) -> SimResult:
    """Run one simulated robot on ``skill`` until Canal says done or ``timeout_s`` passes.
    Before the run, the bridge and the skill's model are each waited for at most
    ``min(timeout_s, 5)`` seconds.

    ``gain`` defaults to ``0.5 * rate_hz`` (1/s) for the first-order lag and to
    ``(0.2 * rate_hz) ** 2`` (1/s^2) for the PD lag.
    """
    if lag not in ("first-order", "pd"):
        raise SimInputError("lag", f"expected lag 'first-order' or 'pd', got {lag!r}")
    check_run(rate_hz, timeout_s, gain)
    dt = 1.0 / rate_hz
    if gain is None:
        gain = 0.5 * rate_hz if lag == "first-order" else (0.2 * rate_hz) ** 2
    rng = np.random.default_rng(seed)
    pending = [(when, np.asarray(offset, dtype=np.float64)) for when, offset in pushes]
    given = None if start is None else np.asarray(start, dtype=np.float64)
    wait_s = min(timeout_s, CONNECT_WAIT_S)
    with PoseStreamer(skill, robot, endpoint=endpoint, zenoh_config=zenoh_config,
                      prefix=prefix, encoding=encoding, session=session, token=token,
                      connect_timeout=wait_s) as ps:
        model = ps.model(timeout=wait_s)
        check_points(int(model["dim"]), given, pushes, keep_out)
        x = random_interior_start(model, rng) if given is None else given
        x0 = x.copy()
        person = None if keep_out is None else _Person(ps, keep_out[0], keep_out[1])
        v = np.zeros_like(x)
        positions: list[np.ndarray] = []
        targets: list[wire.Target] = []
        inside: list[bool] = []
        statuses: dict[str, int] = {}
        missed = pushes_done = 0
        applied: list[PushRecord] = []
        reached = False
        progress = 0.0
        version = None
        answer: wire.Target | None = None
        wait = max(2.0 * dt, 0.05)
        t0 = time.monotonic()
        next_tick = t0
        while True:
            elapsed = time.monotonic() - t0
            if elapsed > timeout_s:
                break
            for k, (when, offset) in enumerate(pending):
                if offset is not None and _push_due(when, elapsed, progress):
                    x = x + offset
                    pending[k] = (when, None)  # type: ignore[assignment]
                    pushes_done += 1
                    applied.append(PushRecord(when, [float(v) for v in offset], elapsed,
                                              progress))
            if person is not None:
                x = person.act(x)
            seq = ps.send(x.tolist(), t=elapsed, restart=not positions)
            positions.append(x.copy())
            got = ps.wait_for(seq, wait)
            if got is None:
                missed += 1
            else:
                answer = got
                targets.append(got)
                statuses[got.status] = statuses.get(got.status, 0) + 1
                # restart_pending: the run's first pose jumped from where this robot's last
                # run left off; no word on where it is and no target: the sim holds still
                # until the restart is made
                if got.status != "restart_pending":
                    inside.append(bool(got.inside or got.done))
                    progress = got.progress
                    if applied:
                        last = applied[-1]
                        if last.inside_after is None:
                            last.inside_after = inside[-1]
                        elif not last.inside_after and last.back_inside_s is None and inside[-1]:
                            last.back_inside_s = time.monotonic() - t0 - last.at_s
                    version = got.model_version
                    if got.done:
                        reached = True
                        break
            if answer is not None and answer.usable and answer.target is not None:
                goal = np.asarray(answer.target)
                if lag == "first-order":
                    x = x + min(gain * dt, 1.0) * (goal - x)
                else:
                    v = v + dt * (gain * (goal - x) - 2.0 * math.sqrt(gain) * v)
                    x = x + dt * v
            next_tick += dt
            now = time.monotonic()
            delay = next_tick - now
            if next_tick > t0 + timeout_s:  # the next tick is past the timeout: the run ends
                time.sleep(max(t0 + timeout_s - now, 0.0))
                break
            if delay > 0:
                time.sleep(delay)
            else:
                next_tick = time.monotonic()
        duration = time.monotonic() - t0
        if person is not None:
            person.finish()
    left = [(when, [float(v) for v in offset]) for (when, _), (_, offset)
            in zip(pushes, pending, strict=True) if offset is not None]
    etas = [t.eta for t in targets if t.eta is not None]
    return SimResult(
        reached_end=reached,
        all_inside=bool(inside) and all(inside),
        n_steps=len(positions),
        positions=np.array(positions),
        targets=targets,
        inside=np.array(inside, dtype=bool),
        min_eta=min(etas) if etas else math.nan,
        max_eta=max(etas) if etas else math.nan,
        duration=duration,
        start=x0,
        model_version=version,
        statuses=statuses,
        missed=missed,
        pushes_done=pushes_done,
        pushes_pending=left,
        seed=seed,
        pushes=applied,
        held=0 if person is None else person.held,
        corrections=[] if person is None else person.versions,
        refused=[] if person is None else person.refused,
    )


__all__ = ["Push", "SimResult", "describe_pending", "random_interior_start", "run_sim"]
