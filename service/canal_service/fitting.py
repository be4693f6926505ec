"""Fits run in a worker process of their own: bounded in server time, cancellable, and their
memory returns to the operating system when they end.

A fit is pure numpy/scipy work that cannot be interrupted from another thread, so it runs
in a child process (forked from a forkserver that has canal_core imported: ~10 ms to start).
The request's thread waits for the answer and kills the child when

* the fit has used ``max_seconds`` of server time (``CANAL_FIT_MAX_SECONDS``),
* the skill is deleted meanwhile (:meth:`FitRunner.cancel_skill`), or
* the client went away (the route sets the request's cancel event).

The work itself stops: the process is gone, and so is every byte it allocated. Before
starting, :func:`fit_cost_seconds` estimates the fit's time from its sizes; a fit estimated
to need more than the cap is refused at once, naming the setting and what makes it cheaper.
A fit estimated below :data:`IN_PROCESS_BELOW_SECONDS` (a few demonstrations of a few
hundred samples) runs in the calling thread: starting a process would cost more than it.

Routes (:mod:`canal_core.routes`): the service clusters the demonstrations into routes
before the job (:func:`route_labels`, bounded by :func:`route_cost_seconds`), so the job
knows them and its estimate counts every fit it makes: the canal of all the demonstrations
and, with several routes, one per route (about twice a single fit's work). The worker then
answers a :class:`canal_core.Routes` instead of a canal.
"""

from __future__ import annotations

import logging
import multiprocessing
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from typing import Any

import numpy as np
import numpy.typing as npt

import canal_core
from canal_core import errors as core_errors

from .errors import FitCancelled, FitTooSlow, SkillNotFound

log = logging.getLogger("canal_service")

FloatArray = npt.NDArray[np.float64]

#: Seconds per unit of work, below every rate measured (DTW: 8e-7 s per cell on an idle
#: core, 3.5e-6 on a loaded one; locating samples: 9e-9 s per sample and section), so a fit
#: is refused beforehand only when even this rate cannot finish it in time.
#: ``bench/fit_bound.py`` measures the real rates beside these.
SECONDS_PER_DTW_CELL = 5e-7
SECONDS_PER_SAMPLE_SECTION = 2e-9
#: Seconds per point pair the route clustering compares (R1 of canal_core.routes), below
#: its measured rate (about 1e-8 s per pair and coordinate on an idle core).
SECONDS_PER_ROUTE_PAIR = 5e-9
#: Seconds per correction sample and section when a refit re-applies the skill's corrections
#: (locating the path among the sections), below its measured rate (5e-8 to 7e-8 s on a
#: loaded core, ``canal_core.corrections.corrected_canal``).
SECONDS_PER_CORRECTION_SAMPLE_SECTION = 2e-8
#: Fits estimated below this run in the calling thread, not in a worker process.
IN_PROCESS_BELOW_SECONDS = 0.01
#: What a fit imports beyond canal_core, loaded once by the forkserver.
FIT_IMPORTS = ("scipy.interpolate", "scipy.linalg", "scipy.ndimage", "scipy.spatial.transform")
#: How often the waiting thread looks at the clock and the cancel events.
POLL_SECONDS = 0.05


@dataclass(frozen=True)
class FitJob:
    """Everything ``canal_core.fit`` is called with (pickled to the worker)."""

    demos: list[FloatArray]
    timestamps: list[FloatArray | None] | None
    #: None: the fit's timing test chooses the clock.
    by_time: bool | None
    orientations: list[FloatArray | None] | None
    options: dict[str, Any] = field(default_factory=dict)
    #: The route of each demonstration (canal_core.routes.route_labels); None or all 0: one
    #: canal, as a single fit.
    labels: list[int] | None = None
    #: Samples of each correction the refit re-applies to the new canal (none: a plain fit).
    kept_points: list[int] = field(default_factory=list)

    @property
    def n_routes(self) -> int:
        """Routes the job fits (1: a single canal)."""
        return 1 if not self.labels else max(self.labels) + 1

    @property
    def n_points(self) -> list[int]:
        """Samples per demonstration."""
        return [int(d.shape[0]) for d in self.demos]


def fit_cost_seconds(n_points: Sequence[int], n_samples: int, alignment: str,
                     seconds_per_dtw_cell: float = SECONDS_PER_DTW_CELL) -> float:
    """A low estimate of a fit's server time from its sizes.

    The two terms that dominate large fits: DTW fills a band of ``0.2 N`` cells per row of
    an ``N x N`` table per demonstration; locating every sample among the N sections (the
    envelope) costs about ``N`` per sample. Rates are :data:`SECONDS_PER_DTW_CELL` and
    :data:`SECONDS_PER_SAMPLE_SECTION`, chosen low, so a refusal is certain, not a guess.

    Parameters
    ----------
    n_points : sequence of int
        T_j of every demonstration.
    n_samples : int
        N, the number of sections.
    alignment : str
        ``"dtw"`` or another alignment (no DTW table).
    seconds_per_dtw_cell : float
        The DTW rate assumed.
    """
    samples = float(sum(n_points))
    cost = SECONDS_PER_SAMPLE_SECTION * samples * n_samples
    if alignment == "dtw":
        cost += seconds_per_dtw_cell * len(n_points) * 0.2 * float(n_samples) ** 2
    return cost


def reapply_cost_seconds(kept_points: Sequence[int], n_samples: int) -> float:
    """A low estimate of re-applying corrections of ``kept_points`` samples each to a canal
    of ``n_samples`` sections (each is located among every section)."""
    return SECONDS_PER_CORRECTION_SAMPLE_SECTION * float(sum(kept_points)) * n_samples


def route_cost_seconds(n_demos: int, dim: int) -> float:
    """A low estimate of the route clustering's time for ``n_demos`` demonstrations."""
    return SECONDS_PER_ROUTE_PAIR * canal_core.routes.route_work(n_demos) * dim


def _fitted(job: FitJob) -> tuple[Any, ...]:
    """``canal_core.fit`` of ``job`` as a reply: ("ok", canal or Routes), ("refused", error
    class name, message, field) or ("failed", what)."""
    try:
        canal: Any
        if job.n_routes > 1:
            canal = canal_core.fit_routes(job.demos, job.timestamps, labels=job.labels,
                                          by_time=job.by_time, orientations=job.orientations,
                                          **job.options)
        else:
            canal = canal_core.fit(job.demos, timestamps=job.timestamps, by_time=job.by_time,
                                   orientations=job.orientations, **job.options)
    except canal_core.CanalError as exc:
        return ("refused", type(exc).__name__, exc.message, exc.field)
    except Exception as exc:  # sent back so the service logs it as its own error
        return ("failed", f"{type(exc).__name__}: {exc}")
    return ("ok", canal)


def _work(conn: Connection, job: FitJob) -> None:
    """The worker process: fit, send the canal (or canal_core's refusal) back, exit."""
    try:
        conn.send(_fitted(job))
    finally:
        conn.close()


def _context() -> Any:
    # Not fork: the service has threads (uvicorn, the recorder, Zenoh) whose locks a forked
    # child would inherit held. The forkserver is a clean interpreter with canal_core loaded.
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    ctx = multiprocessing.get_context("forkserver")
    # Everything a worker runs is loaded here once, not in every worker: this module (its
    # package brings FastAPI and SQLAlchemy, ~1 s to import) and the scipy parts canal_core
    # imports where a fit needs them.
    ctx.set_forkserver_preload(["__main__", __name__, *FIT_IMPORTS])
    return ctx


class FitRunner:
    """Runs fits in worker processes within ``max_seconds`` each; cancellable per skill.

    Parameters
    ----------
    max_seconds : float
        Server time one fit may take (``CANAL_FIT_MAX_SECONDS``).
    """

    def __init__(self, max_seconds: float) -> None:
        self.max_seconds = max_seconds
        #: The rate the estimate assumes for DTW (seconds per cell): the estimate is a lower
        #: bound, and a fit it lets through is still stopped at the cap.
        self.seconds_per_dtw_cell = SECONDS_PER_DTW_CELL
        self._ctx = _context()
        self._lock = threading.Lock()
        self._running: dict[str, set[threading.Event]] = {}
        #: Worker processes stopped before their end (cap, deletion, client gone).
        self.killed = 0
        #: pid -> skill of the worker processes running now.
        self.workers: dict[int, str] = {}

    def check_cost(self, job: FitJob) -> float:
        """The estimated seconds of ``job``; :class:`FitTooSlow` when above the cap."""
        n_samples = int(job.options.get("n_samples", canal_core.FitOptions().n_samples))
        alignment = str(job.options.get("alignment", canal_core.FitOptions().alignment))
        estimate = fit_cost_seconds(job.n_points, n_samples, alignment,
                                    self.seconds_per_dtw_cell)
        labels = job.labels or []
        if job.n_routes > 1:
            # One more fit per route, over that route's demonstrations.
            points = job.n_points
            for k in range(job.n_routes):
                estimate += fit_cost_seconds([points[j] for j, r in enumerate(labels) if r == k],
                                             n_samples, alignment, self.seconds_per_dtw_cell)
        # The corrections a refit keeps are re-applied after the fit, in the request's thread.
        estimate += reapply_cost_seconds(job.kept_points, n_samples)
        if estimate > self.max_seconds:
            cheaper = "fewer n_samples" + (", alignment 'spline'" if alignment == "dtw" else "")
            if job.kept_points:
                cheaper += ", keep_corrections false"
            raise FitTooSlow(
                f"expected a fit within CANAL_FIT_MAX_SECONDS = {self.max_seconds:g} s of server "
                f"time, got one estimated at {estimate:.3g} s at least ({len(job.demos)} "
                f"demonstrations, {sum(job.n_points)} samples, n_samples {n_samples}, "
                f"alignment {alignment!r}" + (f", {job.n_routes} routes" if job.n_routes > 1
                                              else "")
                + (f", {len(job.kept_points)} correction{'s' if len(job.kept_points) > 1 else ''}"
                   f" of {sum(job.kept_points)} samples to re-apply" if job.kept_points else "")
                + f"); ask for {cheaper}" + (", routes 1" if job.n_routes > 1 else "")
                + " or fewer demonstrations",
                field="n_samples")
        return estimate

    def check_route_cost(self, n_demos: int, dim: int) -> float:
        """The estimated seconds of clustering ``n_demos`` demonstrations into routes;
        :class:`FitTooSlow` (naming ``routes``) when above the cap."""
        estimate = route_cost_seconds(n_demos, dim)
        if estimate > self.max_seconds:
            raise FitTooSlow(
                f"expected the route clustering within CANAL_FIT_MAX_SECONDS = "
                f"{self.max_seconds:g} s of server time, got one estimated at {estimate:.3g} s "
                f"at least ({n_demos} demonstrations); ask for routes 1 or fewer "
                "demonstrations", field="routes")
        return estimate

    def cancel_skill(self, skill: str) -> int:
        """Stop every running fit of ``skill`` (it was deleted); how many were running."""
        with self._lock:
            events = list(self._running.get(skill, ()))
        for event in events:
            event.set()
        return len(events)

    def run(self, skill: str, job: FitJob, cancel: threading.Event | None = None
            ) -> canal_core.Canal | canal_core.Routes:
        """Fit ``job`` in a worker process; the canal (:class:`canal_core.Routes` when the job
        has several routes), or canal_core's error re-raised.

        Raises :class:`FitTooSlow` (estimate or cap reached) or :class:`FitCancelled`
        (``cancel`` set, or the skill deleted): the worker is killed first.
        """
        if self.check_cost(job) < IN_PROCESS_BELOW_SECONDS:
            # Starting a process costs more than such a fit (10-500 ms on a loaded machine
            # against a few ms): it runs here, far inside every bound.
            return _canal_of(_fitted(job))
        event = threading.Event()  # set by cancel_skill
        with self._lock:
            self._running.setdefault(skill, set()).add(event)
        receiver, sender = self._ctx.Pipe(duplex=False)
        process = self._ctx.Process(target=_work, args=(sender, job), daemon=True,
                                    name=f"canal-fit-{skill}")
        try:
            process.start()
            sender.close()
            with self._lock:
                self.workers[process.pid] = skill
            reply = self._wait(process, receiver, cancel or threading.Event(), event, skill)
        finally:
            if process.is_alive():
                process.kill()
                self.killed += 1
            if process.pid is not None:
                process.join(5)
            receiver.close()
            with self._lock:
                self.workers.pop(process.pid, None)
                events = self._running.get(skill)
                if events is not None:
                    events.discard(event)
                    if not events:
                        del self._running[skill]
        return _canal_of(reply)

    def _wait(self, process: Any, receiver: Connection, cancel: threading.Event,
              deleted: threading.Event, skill: str) -> Any:
        deadline = time.monotonic() + self.max_seconds
        while True:
            if receiver.poll(POLL_SECONDS):
                try:
                    return receiver.recv()
                except EOFError:
                    pass  # the worker died without a word: said below
                raise RuntimeError(f"the fit's worker process ended with exit code "
                                   f"{process.exitcode} before answering")
            if deleted.is_set():
                raise SkillNotFound(f"skill {skill!r} was deleted while it was being fitted",
                                    field="name")
            if cancel.is_set():
                raise FitCancelled("the fit was cancelled before it ended: its client left",
                                   field="fit")
            if time.monotonic() > deadline:
                raise FitTooSlow(
                    f"expected a fit within CANAL_FIT_MAX_SECONDS = {self.max_seconds:g} s of "
                    f"server time, got one still running after {self.max_seconds:g} s: it was "
                    "stopped; ask for fewer n_samples or fewer demonstrations, or raise the "
                    "setting", field="n_samples")
            if not process.is_alive() and not receiver.poll(0):
                raise RuntimeError(f"the fit's worker process ended with exit code "
                                   f"{process.exitcode} before answering")


def _canal_of(reply: Any) -> canal_core.Canal | canal_core.Routes:
    kind = reply[0]
    if kind == "ok":
        canal: canal_core.Canal | canal_core.Routes = reply[1]
        return canal
    if kind == "refused":
        _kind, name, message, at = reply
        cls = getattr(core_errors, name, core_errors.CanalError)
        raise cls(message, field=at)
    raise RuntimeError(f"the fit failed in its worker process: {reply[1]}")
