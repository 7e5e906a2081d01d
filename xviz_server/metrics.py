"""The server's metrics, exposed at ``/metrics`` in Prometheus text format.

Each server owns its registry, so that several servers (in tests, say) can
run in one process.
"""

from __future__ import annotations

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, generate_latest
from prometheus_client.exposition import CONTENT_TYPE_LATEST

__all__ = ["Metrics", "CONTENT_TYPE"]

CONTENT_TYPE = CONTENT_TYPE_LATEST
_LATENCY_BUCKETS = (0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0)


class Metrics:
    """Counters, gauges and histograms of one server."""

    def __init__(self) -> None:
        self.registry = registry = CollectorRegistry()
        self.sessions_open = Gauge("xviz_sessions_open", "Sessions now open.", registry=registry)
        self.sessions = Counter("xviz_sessions", "Sessions opened.", registry=registry)
        self.sessions_by_detail = Gauge(
            "xviz_sessions_by_detail",
            "Sessions now open, by the level of detail they are sent.",
            ["level"],
            registry=registry,
        )
        self.frames_sent = Counter(
            "xviz_frames_sent", "State updates sent, by message format.", ["format"], registry=registry
        )
        self.bytes_sent = Counter(
            "xviz_bytes_sent", "Bytes of XVIZ messages sent, by message format.", ["format"], registry=registry
        )
        self.errors = Counter(
            "xviz_errors", "xviz/error messages sent, by kind of problem.", ["kind"], registry=registry
        )
        self.cache_hits = Counter("xviz_cache_hits", "Frame cache hits.", registry=registry)
        self.cache_misses = Counter("xviz_cache_misses", "Frame cache misses (loads).", registry=registry)
        self.cache_evictions = Counter("xviz_cache_evictions", "Frames evicted from the cache.", registry=registry)
        self.cache_bytes = Gauge("xviz_cache_bytes", "Bytes held by the frame cache.", registry=registry)
        self.cache_entries = Gauge("xviz_cache_entries", "Frames held by the frame cache.", registry=registry)
        self.live_drops = Counter(
            "xviz_live_dropped_updates", "Live updates dropped for viewers that fell behind.", registry=registry
        )
        self.record_dropped = Counter(
            "xviz_record_dropped_updates",
            "Live updates not recorded because the disk could not keep up.",
            registry=registry,
        )
        self.record_errors = Counter(
            "xviz_record_errors", "Recordings ended by a write error (or a recorder fault).", registry=registry
        )
        self.file_bytes = Counter(
            "xviz_file_bytes_sent",
            "Bytes of the logs' MCAP files (/api/logs/NAME/file.mcap) handed to clients.",
            registry=registry,
        )
        self.ingest_refused = Counter(
            "xviz_ingest_refused", "Messages from live sources refused at the door.", registry=registry
        )
        self.request_seconds = Histogram(
            "xviz_request_seconds",
            "Time to answer a request, from receipt to its last message, by request type.",
            ["type"],
            buckets=_LATENCY_BUCKETS,
            registry=registry,
        )
        self.first_frame_seconds = Histogram(
            "xviz_first_frame_seconds",
            "Time from a transform_log request to its first state update.",
            buckets=_LATENCY_BUCKETS,
            registry=registry,
        )

        # the counters of each format, looked up once: a live update is counted once per viewer
        self._sent: dict[str, tuple[Counter, Counter]] = {}

    def show_levels(self) -> None:
        """Show every level of detail in ``xviz_sessions_by_detail``, those no session is at with 0.

        Called once the server is ready for sessions: the levels import numpy and the image codecs.
        """
        from .levels import LEVELS

        for level in LEVELS:
            self.sessions_by_detail.labels(level.name)

    def update_sent(self, fmt: str, size: int) -> None:
        """Count a state update of ``size`` bytes sent in message format ``fmt``."""
        counters = self._sent.get(fmt)
        if counters is None:
            counters = self._sent[fmt] = (self.frames_sent.labels(fmt), self.bytes_sent.labels(fmt))
        counters[0].inc()
        counters[1].inc(size)

    def exposition(self) -> bytes:
        """The metrics in Prometheus text format."""
        return generate_latest(self.registry)
