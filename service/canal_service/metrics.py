"""Prometheus metrics, one registry per app so several apps in one process do not collide."""

from __future__ import annotations

import itertools
import math
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram
from prometheus_client.core import HistogramMetricFamily, Metric
from prometheus_client.registry import Collector
from prometheus_client.utils import floatToGoString

#: A bucket bound as Prometheus writes it ("+Inf", "0.0001"), as ``Histogram`` does.
_bound_text: Callable[[float], str] = floatToGoString

_LIVE_BUCKETS = (2.5e-5, 5e-5, 7.5e-5, 1e-4, 1.5e-4, 2e-4, 3e-4, 5e-4, 1e-3, 2.5e-3, 5e-3, 0.01,
                 0.05)
_LATENCY_BUCKETS = (0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0)


class BulkHistogram(Collector):
    """A histogram that takes many observations at once: counts per bucket and a sum added
    by :meth:`add` (the live bridge's worker counts its poses per bucket as plain integers,
    and its metrics thread hands over the deltas), rendered like ``Histogram`` by
    ``collect``. A custom collector is prometheus_client's public way to export values
    counted elsewhere; ``Histogram`` has no bulk observe."""

    def __init__(self, name: str, documentation: str, buckets: tuple[float, ...],
                 registry: CollectorRegistry | None) -> None:
        self.name = name
        self.documentation = documentation
        #: upper bounds, the last one +inf (as ``Histogram`` adds it)
        self.bounds: tuple[float, ...] = (
            tuple(buckets) if buckets[-1] == math.inf else (*buckets, math.inf))
        self._counts = [0] * len(self.bounds)
        self._sum = 0.0
        self._lock = threading.Lock()
        if registry is not None:
            registry.register(self)

    def add(self, counts: list[int], total: float) -> None:
        """Add ``counts[i]`` observations to bucket i (not cumulative) and ``total`` to the sum."""
        with self._lock:
            for i, n in enumerate(counts):
                self._counts[i] += n
            self._sum += total

    def collect(self) -> Iterator[Metric]:
        with self._lock:
            counts, total = list(self._counts), self._sum
        cumulative = list(itertools.accumulate(counts))
        yield HistogramMetricFamily(
            self.name, self.documentation,
            buckets=[(_bound_text(b), n) for b, n in zip(self.bounds, cumulative, strict=True)],
            sum_value=total)


@dataclass
class Metrics:
    """The service's metrics and the registry ``/metrics`` renders."""

    registry: CollectorRegistry = field(default_factory=CollectorRegistry)

    def __post_init__(self) -> None:
        r = self.registry
        self.requests = Counter("canal_http_requests_total", "HTTP requests by route and status",
                                ["method", "route", "status"], registry=r)
        self.latency = Histogram("canal_http_request_duration_seconds", "HTTP request latency",
                                 ["method", "route"], buckets=_LATENCY_BUCKETS, registry=r)
        self.in_flight = Gauge("canal_http_requests_in_flight", "HTTP requests being served",
                               registry=r)
        self.demos_stored = Counter("canal_demonstrations_stored_total",
                                    "Demonstrations stored", ["source"], registry=r)
        self.fits = Counter("canal_fits_total", "Models fitted", registry=r)
        self.fit_seconds = Histogram("canal_fit_duration_seconds", "canal_core.fit wall time",
                                     buckets=_LATENCY_BUCKETS, registry=r)
        self.corrections = Counter("canal_corrections_total",
                                   "Corrections applied (each made a model version), by kind",
                                   ["kind"], registry=r)
        self.corrections_undone = Counter("canal_corrections_undone_total",
                                          "Corrections undone (each made a model version)",
                                          registry=r)
        self.reproductions = Counter("canal_reproductions_total", "Reproductions computed",
                                     ["inside"], registry=r)
        self.reproductions_stopped = Counter(
            "canal_reproductions_stopped_total",
            "Batches of reproductions stopped before their end, by reason (too_slow: over "
            "CANAL_REPRODUCE_MAX_SECONDS; client_left)", ["reason"], registry=r)
        # live bridge (canal_service.bridge)
        self.live_poses = Counter("canal_live_poses_total", "Poses received by the live bridge",
                                  registry=r)
        self.live_targets = Counter("canal_live_targets_total",
                                    "Targets published (answers, including error statuses)",
                                    registry=r)
        self.live_coalesced = Counter("canal_live_poses_coalesced_total",
                                      "Poses not answered because a newer pose of the same "
                                      "stream was queued (overload policy)", registry=r)
        self.live_errors = Counter("canal_live_errors_total",
                                   "Live answers with a status other than ok, by status key",
                                   ["status"], registry=r)
        self.live_streams = Gauge("canal_live_streams", "Active (skill, robot) pose streams",
                                  registry=r)
        self.live_step_seconds = BulkHistogram(
            "canal_live_step_seconds", "Bridge time per pose: dequeue to target published",
            _LIVE_BUCKETS, r)
        self.live_up = Gauge("canal_live_bridge_up", "1 while the live Zenoh bridge runs",
                             registry=r)
        self.live_recorded = Counter("canal_live_poses_recorded_total",
                                     "Poses (with their targets) the bridges handed to the "
                                     "live recorder", registry=r)
        self.live_decimated = Counter("canal_live_poses_decimated_total",
                                      "Poses the bridges answered but did not hand to the live "
                                      "recorder (over recordings_live_hz, or answered with an "
                                      "error); with recordings on, canal_live_poses_total = "
                                      "recorded + decimated", registry=r)
        self.live_model_switches = Counter("canal_live_model_switches_total",
                                           "Streams moved to a newer model version", registry=r)
        self.live_steers = Counter("canal_live_steer_inputs_total",
                                   "Steering inputs the bridges held for their streams",
                                   registry=r)

    def stored_counts(self) -> dict[str, float]:
        """What this process stored that a bridge process reports to the service (a bridge
        process has its own ``Metrics``): the live demonstrations and corrections, by label."""
        out: dict[str, float] = {}
        for key, (sample, label, values) in _STORED.items():
            for value in values:
                got = self.registry.get_sample_value(sample, {label: value})
                if got:
                    out[f"{key}:{value}"] = got
        return out

    def add_stored_counts(self, now: dict[str, float], before: dict[str, float]) -> None:
        """Add a bridge process's :meth:`stored_counts` growth since ``before``."""
        for name, n in now.items():
            grown = n - before.get(name, 0.0)
            key, _, value = name.partition(":")
            if grown > 0 and key in _STORED:
                getattr(self, key).labels(value).inc(grown)


#: Metrics attribute -> (sample name, label, label values) that a bridge process reports.
_STORED: dict[str, tuple[str, str, tuple[str, ...]]] = {
    "demos_stored": ("canal_demonstrations_stored_total", "source", ("zenoh",)),
    "corrections": ("canal_corrections_total", "kind", ("include", "exclude")),
}
