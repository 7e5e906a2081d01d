"""The XVIZ server: WebSocket sessions and a few HTTP endpoints on one port.

HTTP requests that are not WebSocket handshakes get:

* ``GET /`` from a browser: the viewer page (see :mod:`xviz_server.viewer`);
* ``GET /api/logs`` (or ``/logs``, or ``/`` from any other client): the
  catalog, JSON: every log with its format, frame count, time range and
  stream names, and the live feeds;
* ``GET /healthz``: ``ok``;
* ``GET /metrics``: the metrics in Prometheus text format.

A WebSocket connection on ``/ingest/<name>`` is a live source feeding the
live feed ``<name>`` (see :mod:`xviz_server.ingest`); on any other path it
is an XVIZ session (the path may name the log). Beyond ``max_sessions``
open sessions, handshakes are refused with HTTP 503.
"""

from __future__ import annotations

import asyncio
import dataclasses
import logging
import signal
import ssl
from http import HTTPStatus
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import orjson
from websockets.asyncio.server import Server, ServerConnection, serve
from websockets.http11 import Request, Response

from . import __version__
from .auth import token_matches
from .cache import FrameCache
from .connection import Connection
from .datasets import KINDS
from .exceptions import LogError
from .ingest import feed_name, refusal, run_ingest
from .live import LiveRegistry
from .logs import Catalog
from .metrics import CONTENT_TYPE, Metrics
from .providers import Provider
from .providers.datasets import DatasetProvider
from .providers.static_log import StaticLogProvider
from .record import Recorder
from .replay import replay
from .settings import Settings
from .viewer import STATIC_DIR, ViewerPage
from .work import Workers

__all__ = ["XVIZServer", "run"]

logger = logging.getLogger(__name__)

MB = 1 << 20


class XVIZServer:
    """A running server; use as ``async with XVIZServer(settings) as server: ...``."""

    def __init__(self, settings: Settings, data_dir: Path | None) -> None:
        self.settings = settings
        self.data_dir = data_dir
        self.metrics = Metrics()
        self.workers = Workers()
        self.cache = FrameCache(int(settings.cache_mb * MB), self.metrics)
        providers: list[Provider] = [StaticLogProvider(data_dir, self.workers)] if data_dir is not None else []
        datasets = [parse_dataset(text) for text in settings.dataset]
        self._datasets = DatasetProvider(data_dir, datasets, self.workers, {"image_max_width": settings.image_max_width})
        providers.append(self._datasets)
        self.catalog = Catalog(providers, self.cache, self.workers, validate=settings.validate_frames)
        #: The live feeds; programs embedding the server publish with ``server.live.feed(name)``.
        self.live = LiveRegistry(self.workers, on_drop=self.metrics.live_drops.inc)
        self._server: Server | None = None
        self._replay: asyncio.Task[None] | None = None
        self._recorder = Recorder(settings.record, self.live, self.workers) if settings.record else None
        #: The sessions running now.
        self.sessions: set[Connection] = set()
        #: The built-in viewer's page and assets.
        self.viewer = ViewerPage(STATIC_DIR, self.workers)

    @property
    def port(self) -> int:
        """The TCP port listened on (useful when the settings asked for port 0)."""
        assert self._server is not None, "server not started"
        return self._server.sockets[0].getsockname()[1]

    async def start(self) -> None:
        """Find the logs and start listening."""
        names = await self.catalog.scan()
        logger.info("serving %d logs from %s", len(names), self.data_dir or "datasets given on the command line")
        if self._datasets.names:
            await self.workers.warm()  # datasets are converted in the process pool: have it up first
        if self.settings.live_from is not None:
            await self._start_replay(self.settings.live_from)
        self._server = await serve(
            self._handle,
            self.settings.host,
            self.settings.port,
            ssl=self._tls(),
            origins=[*self.settings.allowed_origins, None] if self.settings.allowed_origins else None,
            process_request=self._process_request,
            compression="deflate" if self.settings.compression else None,
            max_size=self.settings.max_message_kb * 1024,
            ping_interval=min(20.0, self.settings.idle_timeout),
            ping_timeout=self.settings.idle_timeout,
            close_timeout=min(10.0, self.settings.idle_timeout),
            server_header=f"xviz-server/{__version__}",
        )
        scheme = "wss" if self.settings.certfile else "ws"
        logger.info("listening on %s://%s:%d/", scheme, self.settings.host, self.port)

    def _tls(self) -> ssl.SSLContext | None:
        """The TLS context for --certfile/--keyfile, or ``None`` for plain ws:// and http://."""
        if self.settings.certfile is None:
            return None
        context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
        context.load_cert_chain(self.settings.certfile, self.settings.keyfile)
        return context

    async def _start_replay(self, directory: Path) -> None:
        """Replay a static log as the live feed named after its folder."""
        catalog = Catalog([StaticLogProvider(directory, self.workers)], self.cache, self.workers)
        (name,) = await catalog.scan() or [None]
        if name is None:
            raise LogError(f"--live-from {directory}: no log in the reference layout there", log=str(directory))
        log = await catalog.open(name)
        feed = self.live.feed(log.name)
        self._replay = asyncio.ensure_future(replay(log, feed, rate=self.settings.rate, loop=self.settings.loop))
        logger.info("replaying %r as a live feed at %gx%s", log.name, self.settings.rate, ", looping" if self.settings.loop else "")

    async def close(self) -> None:
        """Close every session with 1001 (going away) and stop listening."""
        if self._replay is not None:
            self._replay.cancel()
        if self._server is not None:
            self._server.close(close_connections=True)
            await self._server.wait_closed()
            self._server = None
        if self._recorder is not None:
            await self._recorder.close()
        self.workers.close()

    async def __aenter__(self) -> XVIZServer:
        await self.start()
        return self

    async def __aexit__(self, *exc_info: Any) -> None:
        await self.close()

    async def _handle(self, websocket: ServerConnection) -> None:
        assert websocket.request is not None
        if feed_name(websocket.request.path) is not None:
            await run_ingest(websocket, self.live)
            return
        connection = Connection(websocket, self.catalog, self.live, self.metrics, self.settings)
        self.sessions.add(connection)
        try:
            await connection.run()
        finally:
            self.sessions.discard(connection)

    async def _process_request(self, connection: ServerConnection, request: Request) -> Response | None:
        if request.headers.get("Upgrade", "").lower() == "websocket":
            if feed_name(request.path) is not None:
                reason = refusal(request, connection.remote_address, self.settings.ingest_token)
                if reason is not None:
                    logger.warning("refused a live source from %s: %s", connection.remote_address, reason)
                    return connection.respond(HTTPStatus.FORBIDDEN, reason + "\n")
                # Sources push whole frames: point clouds and images, megabytes each.
                connection.protocol.max_message_size = int(self.settings.max_ingest_mb * MB)
                return None
            if self.settings.viewer_token and not token_matches(request, self.settings.viewer_token):
                return connection.respond(HTTPStatus.UNAUTHORIZED, "this server needs a viewer token: ?token= or Authorization: Bearer\n")
            if len(self.sessions) >= self.settings.max_sessions:
                logger.warning("refused a session: %d sessions open", self.settings.max_sessions)
                return connection.respond(HTTPStatus.SERVICE_UNAVAILABLE, "too many sessions, try again later\n")
            return None
        path = urlsplit(request.path).path
        if path == "/healthz":
            return connection.respond(HTTPStatus.OK, "ok\n")
        if path == "/metrics":
            return _response(connection, HTTPStatus.OK, self.metrics.exposition(), CONTENT_TYPE)
        if (page := await self.viewer.respond(connection, request)) is not None:
            return page
        if path in ("/", "/logs", "/api/logs"):
            if self.settings.viewer_token and not token_matches(request, self.settings.viewer_token):
                return connection.respond(HTTPStatus.UNAUTHORIZED, "this server needs a viewer token: ?token= or Authorization: Bearer\n")
            live = [{"name": feed.name, "connected": feed.connected} for feed in self.live]
            body = {"server": f"xviz-server {__version__}", "logs": await self.catalog.describe(), "live": live}
            return _response(connection, HTTPStatus.OK, orjson.dumps(body, option=orjson.OPT_INDENT_2), "application/json")
        return connection.respond(
            HTTPStatus.NOT_FOUND,
            "not found: open a WebSocket for an XVIZ session, or GET /, /api/logs, /healthz or /metrics\n",
        )


def parse_dataset(text: str) -> tuple[str, Path]:
    """``kitti:/data/drive`` as ``("kitti", Path("/data/drive"))``; raises :class:`ValueError`."""
    kind, separator, path = text.partition(":")
    if not separator or not kind or not path:
        raise ValueError(f"--dataset {text!r}: give KIND:PATH, like kitti:/data/2011_09_26_drive_0001_sync")
    if kind not in KINDS:
        raise ValueError(f"--dataset {text!r}: unknown kind {kind!r}; known: {', '.join(sorted(KINDS))}")
    if not Path(path).is_dir():
        raise ValueError(f"--dataset {text!r}: {path} is not a directory")
    return kind, Path(path)


def _response(connection: ServerConnection, status: HTTPStatus, body: bytes, content_type: str) -> Response:
    response = connection.respond(status, "")
    del response.headers["Content-Type"], response.headers["Content-Length"]
    response.headers["Content-Type"] = content_type
    response.headers["Content-Length"] = str(len(body))
    return dataclasses.replace(response, body=body)


async def run(settings: Settings, data_dir: Path) -> None:
    """Serve until SIGINT or SIGTERM, then close every session and stop."""
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for signum in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(signum, stop.set)
    async with XVIZServer(settings, data_dir):
        await stop.wait()
        logger.info("shutting down: closing sessions")
