"""Prometheus metrics, served at ``/metrics`` in the text exposition format.

- ``qem_http_requests_total{route, method, status}`` and
  ``qem_http_request_duration_seconds{route, method}``: every request, those answered
  from memory before FastAPI included (`RequestMetrics` is the outermost middleware);
  ``route`` is the path's template (``/v1/meshes/{id}/lod``), so ids do not make series.
- ``qem_meshes{status}``: meshes by status (queued, building, ready, failed), read from
  the database at each scrape.
- ``qem_builds_finished_total{outcome}`` and ``qem_build_duration_seconds{outcome}``:
  builds this process's job queue saw end (ready, failed, skipped).
- ``qem_cache_hits_total{cache}``, ``qem_cache_misses_total{cache}``,
  ``qem_cache_entries{cache}``, ``qem_cache_used{cache}``: the read path's in-memory
  caches (records, meshes, levels, streams); ``used`` is bytes for levels and streams,
  entries for the others; a miss is a value made or loaded and put in.

Each app has its own registry (tests start many apps in one process).
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable

from prometheus_client import (
    CONTENT_TYPE_LATEST,
    CollectorRegistry,
    Counter,
    Histogram,
    generate_latest,
)
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily
from prometheus_client.registry import Collector

from .lru import CacheStats

__all__ = ["CONTENT_TYPE_LATEST", "Metrics", "RequestMetrics", "route_of"]

# Path -> the route's template; the first that matches wins.
_ROUTES = [
    (re.compile(r"^/v1/meshes/[^/]+/(lod|splits|texture)$"), r"/v1/meshes/{id}/\1"),
    (re.compile(r"^/v1/meshes/[^/]+$"), "/v1/meshes/{id}"),
    (re.compile(r"^/(v1/meshes|healthz|readyz|metrics|openapi\.json|docs|redoc)$"), r"/\1"),
]
# Latency buckets from a cached level (sub-millisecond) to an upload of hundreds of MB.
_BUCKETS = (0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30)
_BUILD_BUCKETS = (0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30, 60, 120, 300, 600)


def route_of(path: str) -> str:
    """The route template of ``path``; ``/`` for anything else (the viewer's files)."""
    for pattern, template in _ROUTES:
        match = pattern.match(path)
        if match:
            return match.expand(template)
    return "/"


class Metrics:
    """The app's registry and its metrics; `watch` adds what is read at scrape time."""

    def __init__(self) -> None:
        self.registry = CollectorRegistry()
        self._scrape_time: _ScrapeTime | None = None
        self.requests = Counter(
            "qem_http_requests", "HTTP requests answered", ["route", "method", "status"],
            registry=self.registry,
        )  # fmt: skip
        self.latency = Histogram(
            "qem_http_request_duration_seconds", "time to answer a request, to its last byte",
            ["route", "method"], buckets=_BUCKETS, registry=self.registry,
        )  # fmt: skip
        self.builds = Counter(
            "qem_builds_finished", "builds that ended, by outcome", ["outcome"],
            registry=self.registry,
        )  # fmt: skip
        self.build_seconds = Histogram(
            "qem_build_duration_seconds", "build time, from claim to outcome", ["outcome"],
            buckets=_BUILD_BUCKETS, registry=self.registry,
        )  # fmt: skip

    def build_finished(self, outcome: str, seconds: float) -> None:
        self.builds.labels(outcome).inc()
        self.build_seconds.labels(outcome).observe(seconds)

    def watch(
        self,
        status_counts: Callable[[], dict[str, int]],
        cache_stats: Callable[[], dict[str, CacheStats]],
    ) -> None:
        """Read these at each scrape, in place of what an earlier run of the app (its
        storage closed since) was read from."""
        self.unwatch()
        self._scrape_time = _ScrapeTime(status_counts, cache_stats)
        self.registry.register(self._scrape_time)

    def unwatch(self) -> None:
        if self._scrape_time is not None:
            self.registry.unregister(self._scrape_time)
            self._scrape_time = None

    def exposition(self) -> bytes:
        return generate_latest(self.registry)


class _ScrapeTime(Collector):
    """What is read when /metrics is asked: meshes by status, the caches' figures."""

    def describe(self):
        return []  # registered without a collection (the storage may not answer yet)

    def __init__(self, status_counts, cache_stats) -> None:
        self._status_counts = status_counts
        self._cache_stats = cache_stats

    def collect(self):
        meshes = GaugeMetricFamily("qem_meshes", "meshes by status", labels=["status"])
        counts = self._status_counts()
        for status in ("queued", "building", "ready", "failed"):
            meshes.add_metric([status], counts.get(status, 0))
        yield meshes
        families = {
            "hits": CounterMetricFamily("qem_cache_hits", "lookups found", labels=["cache"]),
            "misses": CounterMetricFamily("qem_cache_misses", "values made", labels=["cache"]),
            "entries": GaugeMetricFamily("qem_cache_entries", "entries held", labels=["cache"]),
            "used": GaugeMetricFamily("qem_cache_used", "bytes (or entries) held",
                                      labels=["cache"]),
        }  # fmt: skip
        for name, stats in self._cache_stats().items():
            for field, family in families.items():
                family.add_metric([name], getattr(stats, field))
        yield from families.values()


class RequestMetrics:
    """ASGI middleware: counts and times every HTTP request by route, method and status."""

    def __init__(self, app, metrics: Metrics) -> None:
        self.app = app
        self.metrics = metrics

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        started = time.perf_counter()
        status = 500  # what a client sees when the app fails before answering

        async def sending(message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            await send(message)

        try:
            await self.app(scope, receive, sending)
        finally:
            route = route_of(scope["path"])
            self.metrics.requests.labels(route, scope["method"], str(status)).inc()
            self.metrics.latency.labels(route, scope["method"]).observe(
                time.perf_counter() - started
            )
