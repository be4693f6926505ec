"""Prometheus metrics, one registry per app so several apps in one process do not collide."""

from __future__ import annotations

from dataclasses import dataclass, field

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram

_LATENCY_BUCKETS = (0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0)


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
        self.reproductions = Counter("canal_reproductions_total", "Reproductions computed",
                                     ["inside"], registry=r)
