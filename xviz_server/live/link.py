"""The connection of one replica to the broker (Redis): clients, state, metrics.

Every command has a short timeout and no retry of its own: a broker that is
down costs a writer or a reader one failed command, never a wait, and the
:class:`~xviz_server.live.broker.Broker` tries again with backoff. The
broker's URL is only ever shown without its password.
"""

from __future__ import annotations

import asyncio
import logging
import os
import secrets
import socket
import time
from typing import cast

from prometheus_client import Counter, Gauge, Histogram
from redis.asyncio import Redis
from redis.asyncio.retry import Retry
from redis.backoff import NoBackoff
from redis.exceptions import RedisError

from ..logfmt import redact_password
from ..metrics import Metrics
from .redis_wire import Wire

__all__ = ["Link", "FAILURES", "BLOCK_MS", "COMMAND_TIMEOUT", "cancel"]

logger = logging.getLogger("xviz_server.broker")

#: Seconds to connect to the broker, and to wait for the answer to one command.
CONNECT_TIMEOUT = 1.0
COMMAND_TIMEOUT = 2.0
#: Milliseconds a reader's XREAD waits for new entries.
BLOCK_MS = 1000
#: What a failed command raises: the client's errors, the socket's, and a wait that timed out.
FAILURES = (RedisError, OSError, asyncio.TimeoutError)


class BrokerMetrics:
    """The broker's counters, in the server's registry."""

    def __init__(self, metrics: Metrics) -> None:
        registry = metrics.registry
        self.up = Gauge("xviz_broker_up", "1 while the broker answers, else 0.", registry=registry)
        self.writes = Counter(
            "xviz_broker_writes", "Entries written to the broker (metadata, updates, keyframes).", registry=registry
        )
        self.written_bytes = Counter(
            "xviz_broker_written_bytes", "Bytes of updates written to the broker.", registry=registry
        )
        self.reads = Counter(
            "xviz_broker_reads", "Entries read from the broker for feeds held by other replicas.", registry=registry
        )
        self.drops = Counter(
            "xviz_broker_dropped_updates",
            "Updates lost between replicas, by reason: down, full, behind or error (not written by the owner), "
            "gap (found missing by a reader), garbage (entries a reader refused: not what an owner writes, or what "
            "ingest refuses).",
            ["reason"],
            registry=registry,
        )
        self.restarts = Counter(
            "xviz_broker_reader_restarts",
            "Readers of feeds of other replicas that failed and started again (see /healthz for one that keeps failing).",
            registry=registry,
        )
        self.readers = Gauge(
            "xviz_broker_readers",
            "Feeds of other replicas being read from the broker (while they have viewers here).",
            registry=registry,
        )
        self.lag = Histogram(
            "xviz_broker_lag_seconds",
            "Time from an update's entry in the broker to its reader on another replica.",
            buckets=(0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0),
            registry=registry,
        )


class Link:
    """This replica's clients of the broker at ``url``, and whether it answers.

    :attr:`redis` is for short commands, :attr:`blocking` for XREAD with
    BLOCK (one connection per waiting reader); a feed's updates go through
    connections of their own (:meth:`wire`). :attr:`id` names this replica
    in the broker: host, process and a random part, so that a restarted
    process is another replica.
    """

    def __init__(self, url: str, metrics: Metrics) -> None:
        self.url = redact_password(url)
        self._target = url
        self.id = f"{socket.gethostname()}:{os.getpid()}:{secrets.token_hex(3)}".encode()
        self.metrics = BrokerMetrics(metrics)
        self.redis = _client(url, COMMAND_TIMEOUT)
        self.blocking = _client(url, BLOCK_MS / 1000 + COMMAND_TIMEOUT)
        self.up = False
        self._since = time.monotonic()
        self._problem: str | None = None  # why it is down; None while up or before the first answer

    @property
    def down(self) -> bool:
        """Whether the broker failed to answer since it last did (not while connecting at first)."""
        return not self.up and self._problem is not None

    def succeeded(self) -> None:
        """The broker answered."""
        if not self.up:
            logger.info("broker %s: connected%s", self.url, "" if self._problem is None else " again")
            self.up, self._since, self._problem = True, time.monotonic(), None
            self.metrics.up.set(1)

    def failed(self, exc: BaseException) -> None:
        """A command failed for want of the broker; said once per outage."""
        if self.up or self._problem is None:
            self._problem = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
            logger.warning(
                "broker %s: unreachable (%s); serving recorded logs and this replica's feeds, retrying",
                self.url,
                self._problem,
            )
            self.up, self._since = False, time.monotonic()
            self.metrics.up.set(0)

    def health(self) -> str:
        """One line for ``/healthz``."""
        seconds = time.monotonic() - self._since
        if self.up:
            return f"broker {self.url}: up for {seconds:.0f} s"
        if self._problem is None:
            return f"broker {self.url}: connecting for {seconds:.0f} s"
        return f"broker {self.url}: down for {seconds:.0f} s ({self._problem}); retrying"

    async def read(self, stream: str, last: bytes, count: int) -> list[tuple[bytes, dict[bytes, bytes]]]:
        """The entries of ``stream`` after id ``last``, at most ``count``, waiting up to :data:`BLOCK_MS` for one."""
        answer = await self.blocking.xread({stream: last}, count=count, block=BLOCK_MS)
        return [
            entry
            for _, entries in cast(list[tuple[bytes, list[tuple[bytes, dict[bytes, bytes]]]]], answer or [])
            for entry in entries
        ]

    async def wire(self, name: str) -> Wire:
        """A connection of its own to the broker, named ``name`` in its ``CLIENT LIST`` (see :mod:`.wire`)."""
        return await Wire.open(self._target, name, CONNECT_TIMEOUT)

    async def fields(self, key: str, *names: str) -> list[bytes | None]:
        """Fields of the hash ``key``, ``None`` for those it lacks."""
        return cast(list[bytes | None], await self.redis.hmget(key, list(names)))

    async def close(self) -> None:
        await self.redis.aclose()
        await self.blocking.aclose()


async def cancel(tasks: list[asyncio.Task[None]]) -> None:
    """Cancel ``tasks`` and wait for them, at most :data:`COMMAND_TIMEOUT` seconds.

    The client may turn a cancellation that meets its own timeout into a
    timeout error, which a loop takes for a broker that is down: each loop
    also stops at its next turn once its owner is closed.
    """
    for task in tasks:
        task.cancel()
    if tasks:
        await asyncio.wait(tasks, timeout=COMMAND_TIMEOUT)


def _client(url: str, timeout: float) -> Redis:
    return Redis.from_url(
        url, socket_timeout=timeout, socket_connect_timeout=CONNECT_TIMEOUT, retry=Retry(NoBackoff(), 0), protocol=2
    )
