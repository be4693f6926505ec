"""The pose path: samples in, ratio-rule targets out, on one worker thread.

The worker blocks on its pose channel (GIL released), drains everything else queued without
blocking and handles the drain as one batch: decode every pose, step the trackers of all
streams of one model in **one** vectorised numpy pass over the model's
:class:`canal_core.tracker_bank.TrackerBank` (every stream's tracker state is a slot of its
arrays: no per-tracker Python object on the way in or out), turn the answer arrays into
Python lists once per drain, then encode and put each answer. A stream with
several poses in one drain is stepped in order (one pass per pose). Metrics are plain
integers (:class:`.streams.Counts`); the bridge's metrics thread hands them to Prometheus.

*Overload policy*: when one stream has more than ``coalesce_backlog`` poses queued in one
drain, only its newest pose is answered, and before it the ``restart`` poses among them,
each made as it would be pose by pose; the others are counted per stream (the
target's ``coalesced``) and in ``canal_live_poses_coalesced_total``.

*Recording*: when the bridge records (``BridgeOptions.record_hz`` set), each stream keeps
the poses the recording wants, with their answers, as plain rows: at most ``record_hz`` per
second (0: every pose), plus every pose whose answer flips the status, ``inside`` or
``done``. The worker counts per stream what it received, answered, coalesced and answered
with an error; :meth:`PosePath.take_record` hands rows and count deltas to the bridge's
recording thread (under ``rec_lock``, which the worker holds for one drain at a time), so
every pose handled is either a row or counted as decimated.

*A skill's first pose* when its model is not loaded yet (beyond the preload bound, or
evicted after ``preload_keep_s``): loading takes milliseconds (a database read, decoding
the canal, building the tracker tables), and on the worker that would stall every other
robot. The worker parks the skill's samples instead and hands the skill to the bridge's
loader thread (:attr:`PosePath.loads`), which loads the model, installs it and answers the
parked samples in order, all under ``rec_lock`` (no drain runs meanwhile, and later samples
of the skill queue behind the parked ones). At most :data:`.streams.PARK_MAX` skills are parked at
once; beyond that (a flood of new names) the worker loads itself, as it does when no loader
runs (a :class:`PosePath` used without a bridge).

Security (:mod:`.streams`): a key chunk that is not a plain name is refused and counted as
``bad_key``; each stream answers only on its own target key.
"""

from __future__ import annotations

import bisect
import logging
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from .decode import Decoder
from .models import ModelEntry
from .step import Stepper
from .tap import RecordTap

log = logging.getLogger("canal_service.bridge")

MAX_DRAIN = 4096


class PosePath(Decoder, Stepper, RecordTap):
    """The streams of one bridge and the worker that answers their poses, in layers of one
    concern: :mod:`.streams` (the stream table), :mod:`.decode`, :mod:`.step`,
    :mod:`.answers` and :mod:`.tap` (the recording tap); this one runs the worker."""

    def work(self, recv: Callable[[], Any], try_recv: Callable[[], Any]) -> None:
        """The worker loop: ``recv`` blocks for a sample (raises, or returns None, when the
        channel closes); ``try_recv`` returns one or None."""
        counts = self.counts
        clock = time.perf_counter
        # NumPy keeps its error state per thread: set once here instead of an errstate
        # context per drain. Poses at 1e308 overflow in the step; they answer outside_canal.
        np.seterr(all="ignore")
        bounds = counts.step_bounds
        buckets = counts.step_buckets
        while True:
            counts.waiting = True
            try:
                sample = recv()
            except Exception:  # channel closed: shutting down
                return
            if sample is None:
                return
            counts.waiting = False
            started = clock()
            batch = [sample]
            drained = False
            while len(batch) < MAX_DRAIN:
                nxt = try_recv()
                if nxt is None:
                    drained = True
                    break
                batch.append(nxt)
            try:
                self._handle(batch)
            except Exception:
                log.exception("live step failed")
                counts.errors["internal_error"] += 1
            if drained:
                counts.last_idle = time.monotonic()
            # the step histogram as plain ints: each pose of the drain observes its share
            seconds = clock() - started
            n = len(batch)
            buckets[bisect.bisect_left(bounds, seconds / n)] += n
            counts.step_sum += seconds
            counts.drains += 1

    def batch(self, batch: list[Any]) -> None:
        """Decode, group, step and answer one drain of the pose channel (any thread)."""
        with np.errstate(all="ignore"):  # 1e308 poses overflow; they answer outside
            self._handle(batch)

    def _handle(self, batch: list[Any]) -> None:
        """:meth:`batch` on the worker, whose NumPy error state is already "ignore"."""
        with self.rec_lock:
            self._handle_locked(batch)

    def _handle_locked(self, batch: list[Any]) -> None:
        self.now_ns = time.time_ns()
        for jobs in self.decode_batch(batch):
            for entry, group, targets, obstacles in self.step(jobs):
                self.answer_all(entry, group, targets, obstacles)

    def load_parked(self) -> None:
        """The loader thread: load each parked skill's model off the worker, then install
        it and answer the skill's parked samples in one ``rec_lock`` hold (so no drain
        answers a later sample of the skill first). Returns when ``loads`` gets None."""
        loads = self.loads
        assert loads is not None
        while True:
            skill = loads.get()
            if skill is None:
                return
            try:
                entry: ModelEntry | None = self.models.load(skill)
            except Exception:  # the database is away: the answers say so (internal_error)
                log.exception("loading the model of %r failed", skill)
                entry = None
            with self.rec_lock, np.errstate(all="ignore"):
                if entry is not None:
                    self.models.install(skill, entry)
                samples = self.parked.pop(skill, [])
                self._flushing = True  # a failed load is retried once, here, not parked again
                try:
                    if samples:
                        self._handle_locked(samples)
                except Exception:
                    log.exception("answering the first poses of %r failed", skill)
                    self.counts.errors["internal_error"] += 1
                finally:
                    self._flushing = False
