"""The XVIZ server: WebSocket sessions and a few HTTP endpoints on one port.

GET and HEAD are served (see :mod:`xviz_server.gate`); HTTP requests that are
not WebSocket handshakes get, each with the headers of :data:`xviz_server.viewer.HEADERS`:

* ``GET /`` from a browser: the viewer page (see :mod:`xviz_server.viewer`);
* ``GET /api/logs`` (or ``/logs``, or ``/`` from any other client): a page
  of the catalog (see :mod:`xviz_server.catalog`), JSON: logs with their
  format, frame count, time range and stream names, searched and paged by
  the query's parameters, and on the first page the live feeds;
  ``GET /api/logs/NAME``: every fact the catalog has of one log;
* ``GET /api/logs/NAME/export?start=&end=``: a clip of a log as an MCAP
  file (see :mod:`xviz_server.foxglove.export`);
* ``GET /api/logs/NAME/file.mcap``: the whole log as an MCAP file served
  with byte ranges, for the Foxglove and Lichtblick apps to seek in (see
  :mod:`xviz_server.foxglove.seekable` and :mod:`xviz_server.ranges`);
  other origins may read it (CORS, within ``--allowed-origin`` when set),
  and ``OPTIONS`` of it is a CORS preflight's answer;
* ``GET /healthz``: ``ok`` (then, with ``--broker``, a line on the broker's
  state, and one for each reader of a feed that keeps failing), or HTTP 503
  saying what is broken (a worker process pool that lost a process and is
  not yet replaced);
* ``GET /metrics``: the metrics in Prometheus text format.

A WebSocket connection on ``/ingest/<name>`` is a live source feeding the
live feed ``<name>`` (see :mod:`xviz_server.live.ingest`); on any other path it
is a session (the path may name the log): a Foxglove session when the
handshake offers one of :data:`~xviz_server.foxglove.protocol.SUBPROTOCOLS`
(the first of them it offers is chosen), else an XVIZ session. Beyond ``max_sessions``
open sessions, handshakes are refused with HTTP 503.
"""

from __future__ import annotations

import asyncio
import dataclasses
import errno
import gc
import importlib
import ipaddress
import logging
import os
import signal
import tempfile
import urllib.parse
from collections.abc import Sequence
from http import HTTPStatus
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import urlsplit

import orjson
from websockets.asyncio.server import Server, ServerConnection, serve
from websockets.datastructures import MultipleValuesError
from websockets.http11 import Request, Response
from websockets.typing import Origin, Subprotocol

from .auth import feed_name, ingest_refusal, token_matches
from .cache import FrameCache
from .catalog import Indexer, parse_query
from .datasets import DATASET_KINDS, GENERATED, dataset_options, dataset_problem
from .exceptions import ConfigError, LogError, LogNotFound, QueryError, XVIZError
from .foxglove.protocol import SUBPROTOCOLS
from .framing import OPEN_TIMEOUT, FramingConnection, StreamedResponse, streamed
from .gate import ALLOW, GatedConnection
from .layout import LOG, check_log_name
from .metrics import CONTENT_TYPE, Metrics
from .settings import Settings
from .store import data_roots
from .tls import server_context
from .version import __version__
from .viewer import STATIC_DIR, ViewerPage
from .work import Workers

if TYPE_CHECKING:
    import ssl

    from .foxglove.connection import FoxgloveConnection
    from .foxglove.seekable import BuiltFile, LogFiles
    from .live import LiveRegistry
    from .live.broker import Broker
    from .live.record import Recorder
    from .logs import LogShelf
    from .xviz.connection import Connection

__all__ = ["XVIZServer", "run"]

logger = logging.getLogger(__name__)

MB = 1 << 20
#: Where one log's facts are asked for: ``/api/logs/NAME``.
LOG_PATH = "/api/logs/"
#: Seconds that closing the server may take before the connections still open are aborted.
SHUTDOWN_TIMEOUT = 10.0
#: Messages a connection holds received and not yet handled before it stops reading its socket: a client's
#: messages are requests, handled one at a time, and each may be ``max_message_kb`` (websockets' default is 16).
MAX_QUEUE = 2
#: What sessions need and the listing does not (the codecs, numpy, the providers, Foxglove's schemas):
#: imported once the server listens (see :meth:`XVIZServer.start`).
SESSION_MODULES = (
    "logs",
    "live",
    "xviz.connection",
    "foxglove.connection",
    "foxglove.translate",
    "foxglove.export",
    "foxglove.seekable",
    "live.ingest",
)
#: Seconds a request for a log's file may wait for the file to be made (on first request); the making goes on after.
FILE_WAIT = 600.0
#: What the answers about a log's file (``/api/logs/NAME/file.mcap``) let a page of another origin read.
FILE_EXPOSED = "Accept-Ranges, Content-Length, Content-Range, ETag, Last-Modified"
#: What a page of another origin may send with its request for a log's file: the headers its answer reads.
FILE_REQUEST_HEADERS = "Range, If-Range, If-Match, If-None-Match, If-Modified-Since"
#: How long a browser may keep a preflight's answer (Chromium keeps it at most 2 hours).
PREFLIGHT_SECONDS = 7200


class _Connection(GatedConnection, FramingConnection):
    """The server's connections: GET requests only (:mod:`.gate`), large frames sent without a copy (:mod:`.framing`)."""


class XVIZServer:
    """A running server; use as ``async with XVIZServer(settings) as server: ...``.

    It serves the logs and datasets under ``settings.data_dir``, the
    datasets named by ``settings.dataset``, and the live feeds published to
    :attr:`live`. Raises :class:`ValueError` for a ``dataset`` that is not
    ``KIND:PATH``.
    """

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.metrics = Metrics()
        self.workers = Workers()
        self.cache = FrameCache(int(settings.cache_mb * MB), self.metrics)
        self._roots = data_roots(settings)
        self._datasets = [parse_dataset(text) for text in settings.dataset]
        for kind, path, _ in self._datasets:
            if (problem := dataset_problem(kind, path)) is not None:
                logger.warning("--dataset %s:%s: %s", kind, path, problem)
        #: The persistent catalog: what ``GET /api/logs`` lists, kept current in the background.
        self.indexer = Indexer(
            self._roots,
            self.workers,
            state_dir=settings.state_dir,
            poll=settings.catalog_poll,
            store_poll=settings.catalog_store_poll,
        )
        self._shelf: LogShelf | None = None
        self._files: LogFiles | None = None
        self._live: LiveRegistry | None = None
        self._ready = asyncio.Event()  # set once sessions can be served
        self._server: Server | None = None
        self._replay: asyncio.Task[None] | None = None
        self._recorder: Recorder | None = None
        #: Shares the live feeds with the other replicas, with ``--broker``.
        self.broker: Broker | None = None
        #: The sessions running now.
        self.sessions: set[Connection | FoxgloveConnection] = set()
        self._exporting: set[ServerConnection] = set()  # connections of the exports and files admitted, until they end
        #: The built-in viewer's page and assets.
        self.viewer = ViewerPage(
            STATIC_DIR, self.workers, settings.map_token, settings.viewer_token, settings.frame_ancestors
        )

    @property
    def shelf(self) -> LogShelf:
        """What opens the logs that sessions name (set once started)."""
        assert self._shelf is not None, "server not started"
        return self._shelf

    @property
    def live(self) -> LiveRegistry:
        """The live feeds (set once started); programs embedding the server publish with ``server.live.feed(name)``."""
        assert self._live is not None, "server not started"
        return self._live

    @property
    def port(self) -> int:
        """The TCP port listened on (useful when the settings asked for port 0)."""
        assert self._server is not None, "server not started"
        return self._server.sockets[0].getsockname()[1]

    async def start(self) -> None:
        """Start listening, then get ready for sessions.

        The server listens once the catalog's database is open: from then
        on ``GET /api/logs``, ``/metrics`` and the viewer page are answered,
        while what sessions need is imported (in a thread), the logs and
        datasets are found and the live feeds start; a session, an export or
        ``/healthz`` asked for meanwhile waits until that is done, which is
        when this returns. The worker processes start when a job first needs
        them (at once, after listening, when datasets are served).

        Raises :class:`~xviz_server.exceptions.ConfigError`, with the setting
        to change, for TLS files that cannot serve, an address that cannot be
        listened on and a ``--record`` folder that cannot be written.
        """
        tls = server_context(self.settings.certfile, self.settings.keyfile) if self.settings.certfile else None
        if self.settings.record is not None:
            await asyncio.to_thread(_check_record_folder, self.settings.record)
        await self.indexer.open()
        await self._listen(tls)
        await self.workers.io(_import_session_modules)
        self.metrics.show_levels()
        from .live import LiveRegistry
        from .logs import LogShelf

        self._live = LiveRegistry(self.workers, on_drop=self.metrics.live_drops.inc)
        if self.settings.record is not None:
            from .live.record import Recorder

            self._recorder = Recorder(
                self.settings.record,
                self._live,
                self.workers,
                self.metrics,
                rotate_mb=self.settings.record_rotate_mb,
                max_mb=self.settings.record_max_mb,
                min_free_mb=self.settings.record_min_free_mb,
            )
        if self.settings.broker is not None:
            self.broker = _broker(self.settings, self._live, self.metrics, self.workers)
            self.broker.start()
        self._shelf = LogShelf(
            self._roots,
            self.cache,
            self.workers,
            datasets=self._datasets,
            options={"image_max_width": self.settings.image_max_width},
            validate=self.settings.validate_frames,
            preload_bytes=int(min(self.settings.preload_mb, self.settings.cache_mb / 2) * MB),
        )
        await self._shelf.find_datasets()
        from .foxglove.seekable import LogFiles

        self._files = LogFiles(
            None if self.settings.state_dir is None else self.settings.state_dir / "files",
            self.workers,
            int(self.settings.files_gb * 1e9),
        )
        await self.indexer.start(self._shelf)
        if self._shelf.kinds() - {LOG}:
            await self.workers.warm()  # datasets are converted in the process pool: have it up first
        if self.settings.live_from is not None:
            await self._start_replay(self.settings.live_from)
        self._ready.set()

    async def _listen(self, tls: ssl.SSLContext | None) -> None:
        try:
            self._server = await serve(
                self._handle,
                self.settings.host,
                self.settings.port,
                ssl=tls,
                origins=[*map(Origin, self.settings.allowed_origins), None] if self.settings.allowed_origins else None,
                process_request=self._process_request,
                select_subprotocol=_select_subprotocol,
                compression="deflate" if self.settings.compression else None,
                max_size=self.settings.max_message_kb * 1024,
                max_queue=MAX_QUEUE,
                ping_interval=min(20.0, self.settings.idle_timeout),
                ping_timeout=self.settings.idle_timeout,
                close_timeout=min(10.0, self.settings.idle_timeout),
                server_header=f"xviz-server/{__version__}",
                create_connection=_Connection,
                open_timeout=None,  # _Connection times the handshake itself: not the body of a streamed answer
                ssl_handshake_timeout=OPEN_TIMEOUT if tls else None,
            )
        except OSError as exc:
            raise ConfigError(_cannot_listen(self.settings.host, self.settings.port, exc)) from None
        secure = "s" if self.settings.certfile else ""
        logger.info("listening on ws%s://%s:%d/", secure, self.settings.host, self.port)
        logger.info("the viewer page: http%s://%s:%d/", secure, self.settings.host, self.port)
        if self.settings.ingest_token is None:
            # At INFO on a loopback address (a default run: only this machine reaches the server); a WARNING
            # where other hosts reach it, since a reverse proxy on this host makes every client local.
            logger.log(
                logging.INFO if _is_loopback_host(self.settings.host) else logging.WARNING,
                "live ingest (/ingest/NAME) is open to every local process without --ingest-token; "
                "behind a reverse proxy on this host every client is local: set --ingest-token",
            )

    async def _start_replay(self, directory: Path) -> None:
        """Replay a static log as the live feed named after its folder."""
        from .live.replay import replay
        from .logs import LogShelf

        shelf = LogShelf([directory], self.cache, self.workers)
        names = await shelf.scan()
        if not names:
            raise LogError(f"--live-from {directory}: no log in the reference layout there", log=str(directory))
        log = await shelf.open(names[0])
        feed = self.live.feed(log.name)
        self._replay = asyncio.ensure_future(replay(log, feed, rate=self.settings.rate, loop=self.settings.loop))
        logger.info(
            "replaying %r as a live feed at %gx%s",
            log.name,
            self.settings.rate,
            ", looping" if self.settings.loop else "",
        )

    async def close(self) -> None:
        """Stop listening and close every connection with 1001 (going away), in at most :data:`SHUTDOWN_TIMEOUT` s.

        Connections that cannot be closed cleanly by then (a client that
        stopped reading cannot take the closing frame) are aborted; then the
        recordings are finished.
        """
        if self._replay is not None:
            self._replay.cancel()
        if (server := self._server) is not None:
            server.close(close_connections=True)
            try:
                await asyncio.wait_for(asyncio.shield(server.wait_closed()), SHUTDOWN_TIMEOUT)
            except asyncio.TimeoutError:
                stuck = list(server.all_connections)  # closing ones too: .connections has only open ones
                logger.warning(
                    "shutdown: aborting %d connections that did not close in %g s", len(stuck), SHUTDOWN_TIMEOUT
                )
                for connection in stuck:
                    connection.transport.abort()
                await server.wait_closed()
            self._server = None
        if self._shelf is not None:
            self._shelf.close()
        if self._files is not None:
            await self._files.close()
        await self.indexer.close()
        if self.broker is not None:
            await self.broker.close()
        if self._recorder is not None:
            await self._recorder.close()
        self.workers.close()

    async def __aenter__(self) -> XVIZServer:
        try:
            await self.start()
        except BaseException:
            await self.close()
            raise
        return self

    async def __aexit__(self, *exc_info: Any) -> None:
        await self.close()

    async def _handle(self, websocket: ServerConnection) -> None:
        assert websocket.request is not None
        await self._ready.wait()
        from .foxglove.connection import FoxgloveConnection
        from .live.ingest import run_ingest
        from .xviz.connection import Connection

        if feed_name(websocket.request.path) is not None:
            await run_ingest(websocket, self.live, self.workers, self.settings, self.metrics)
            return
        connection: Connection | FoxgloveConnection
        if websocket.subprotocol in SUBPROTOCOLS:
            connection = FoxgloveConnection(websocket, self.shelf, self.live, self.metrics, self.settings)
        else:
            connection = Connection(websocket, self.shelf, self.live, self.metrics, self.settings)
        self.sessions.add(connection)
        try:
            await connection.run()
        finally:
            self.sessions.discard(connection)

    async def _process_request(self, connection: ServerConnection, request: Request) -> Response | None:
        """The answer to ``request``, or ``None`` to accept its WebSocket handshake. A header given on two lines
        that is read as one value is a 400 naming it; any other failure is a 500 that names what was asked
        (websockets' own would say a WebSocket failed to open)."""
        try:
            return await self._answer(connection, request)
        except MultipleValuesError as exc:
            return connection.respond(HTTPStatus.BAD_REQUEST, f"the header {exc.args[0]!r} is given more than once\n")
        except Exception:
            path = urlsplit(request.path).path
            logger.exception("answering GET %s failed", path)
            upgrade = any(value.lower() == "websocket" for value in request.headers.get_all("Upgrade"))
            what = f"a WebSocket session on {path}" if upgrade else f"GET {path}"
            return connection.respond(
                HTTPStatus.INTERNAL_SERVER_ERROR, f"the server failed to answer {what}: see its log\n"
            )

    async def _answer(self, connection: ServerConnection, request: Request) -> Response | None:
        if isinstance(connection, GatedConnection) and connection.preflight:
            return self._preflight(connection, request)
        if request.headers.get("Upgrade", "").lower() == "websocket":
            if feed_name(request.path) is not None:
                reason = ingest_refusal(
                    request, connection.remote_address, self.settings.ingest_token, self.settings.allowed_origins
                )
                if reason is not None:
                    logger.warning("refused a live source from %s: %s", connection.remote_address, reason)
                    return connection.respond(HTTPStatus.FORBIDDEN, reason + "\n")
                # Sources push whole frames: point clouds and images, megabytes each.
                connection.protocol.max_message_size = int(self.settings.max_ingest_mb * MB)
                return None
            if (refused := self._viewer_refusal(connection, request)) is not None:
                return refused
            if self._open() >= self.settings.max_sessions:
                return self._too_many(connection, "a session")
            return None
        path = urlsplit(request.path).path
        if path == "/healthz":
            await self._ready.wait()  # healthy: ready for sessions
            problems = self.workers.health()
            if problems:
                return connection.respond(
                    HTTPStatus.SERVICE_UNAVAILABLE, "".join(f"{problem}\n" for problem in problems)
                )
            # The broker's state is shown, not judged: without it the replica still serves.
            return connection.respond(
                HTTPStatus.OK, "ok\n" + ("" if self.broker is None else f"{self.broker.health()}\n")
            )
        if path == "/metrics":
            if self.settings.protect_metrics and (refused := self._viewer_refusal(connection, request)) is not None:
                return refused
            return _response(connection, HTTPStatus.OK, self.metrics.exposition(), CONTENT_TYPE)
        if (page := await self.viewer.respond(connection, request)) is not None:
            return page
        if path.startswith(LOG_PATH) and (name := _layout_path(path)) is not None:
            if (refused := self._viewer_refusal(connection, request)) is not None:
                return refused
            await self._ready.wait()
            return await self._layout(connection, name)
        if path.startswith(LOG_PATH) and (name := _file_path(path)) is not None:
            if (refused := self._viewer_refusal(connection, request)) is not None:
                return refused
            await self._ready.wait()
            answer = await self._file(connection, request, name)
            answer.headers.update(self._cors(request))
            return answer
        if path.startswith(LOG_PATH) and (name := _export_path(path)) is not None:
            if (refused := self._viewer_refusal(connection, request)) is not None:
                return refused
            await self._ready.wait()
            # A "+" is kept as such: "+2" is a time after the log's start, not " 2".
            query = urlsplit(request.path).query.replace("+", "%2B")
            return await self._export(connection, name, urllib.parse.parse_qs(query, keep_blank_values=True))
        if path in ("/", "/logs", "/api/logs") or path.startswith(LOG_PATH):
            if (refused := self._viewer_refusal(connection, request)) is not None:
                return refused
            status, body = await self._listing(path, request.path)
            return _response(connection, status, orjson.dumps(body, option=orjson.OPT_INDENT_2), "application/json")
        return connection.respond(
            HTTPStatus.NOT_FOUND,
            "not found: open a WebSocket for an XVIZ session, or GET /, /api/logs, /healthz or /metrics\n",
        )

    async def _export(self, connection: ServerConnection, name: str, query: dict[str, list[str]]) -> Response:
        """A clip of log ``name`` as an MCAP file, sent as it is written (see :mod:`xviz_server.foxglove.export`)."""
        from .foxglove.export import export, first_error, parse_range
        from .foxglove.frame import log_plan

        try:
            span = parse_range(query)
            log = await self.shelf.open(name, preload=False)
            positions = span.frames(log)
        except LogNotFound as exc:
            return connection.respond(HTTPStatus.NOT_FOUND, f"{exc}\n")
        except QueryError as exc:
            return connection.respond(HTTPStatus.BAD_REQUEST, f"{exc}\n")
        except XVIZError as exc:
            return connection.respond(HTTPStatus.UNPROCESSABLE_ENTITY, f"{exc}\n")
        if self._open() >= self.settings.max_sessions:
            return self._too_many(connection, "an export")
        self._admit(connection)
        the_plan = await log_plan(log)
        if (error := await first_error(log, the_plan, positions)) is not None:
            logger.warning("refused an export of log %r: its first frame cannot be read: %s", name, error)
            return connection.respond(
                HTTPStatus.UNPROCESSABLE_ENTITY, f"the clip's first frame cannot be read: {error}\n"
            )
        head = connection.respond(HTTPStatus.OK, "")
        del head.headers["Content-Type"]
        head.headers["Content-Type"] = "application/octet-stream"
        filename = name.replace("/", "_") + ".mcap"
        head.headers["Content-Disposition"] = f'attachment; filename="{filename}"'
        return streamed(head, export(log, the_plan, positions, self.workers), self.settings.idle_timeout)

    async def _layout(self, connection: ServerConnection, name: str) -> Response:
        """Lichtblick's first layout for log ``name`` (see :mod:`xviz_server.foxglove.layout`)."""
        from .foxglove.frame import log_plan
        from .foxglove.layout import app_layout

        try:
            log = await self.shelf.open(name, preload=False)
        except LogNotFound as exc:
            return connection.respond(HTTPStatus.NOT_FOUND, f"{exc}\n")
        except XVIZError as exc:
            return connection.respond(HTTPStatus.UNPROCESSABLE_ENTITY, f"{exc}\n")
        layout = app_layout(await log_plan(log))
        return _response(
            connection, HTTPStatus.OK, orjson.dumps(layout, option=orjson.OPT_INDENT_2), "application/json"
        )

    async def _file(self, connection: ServerConnection, request: Request, name: str) -> Response:
        """Log ``name`` as a whole MCAP file, or the byte range of it the request asks for (see :mod:`.ranges`)."""
        from .foxglove.frame import log_plan

        assert self._files is not None
        if isinstance(connection, FramingConnection):
            connection.allow(FILE_WAIT)
        try:
            log = await self.shelf.open(name, preload=False)
            stamp = self.shelf.stamp(name)
            version = ",".join(map(str, stamp)) if stamp else await self.indexer.version(name) or ""
            built = await self._files.get(log, await log_plan(log), version)
        except LogNotFound as exc:
            return connection.respond(HTTPStatus.NOT_FOUND, f"{exc}\n")
        except XVIZError as exc:
            return connection.respond(HTTPStatus.UNPROCESSABLE_ENTITY, f"{exc}\n")
        except OSError as exc:
            logger.warning("cannot make the file of log %r: %s", name, exc)
            return connection.respond(
                HTTPStatus.SERVICE_UNAVAILABLE, f"cannot make the file of log {name!r}: {exc.strerror or exc}\n"
            )
        try:
            response = self._file_answer(connection, request, built)
        except BaseException:
            self._files.release(built)
            raise
        if not isinstance(response, StreamedResponse):  # no body: the file is not read
            self._files.release(built)
        return response

    def _file_answer(self, connection: ServerConnection, request: Request, built: BuiltFile) -> Response:
        """The answer with the file :meth:`LogFiles.get` gave and holds: with a body that releases it once
        closed, or without one."""
        from .ranges import decide

        assert self._files is not None
        answer = decide(request.headers.raw_items(), built.representation)
        if answer.status not in (HTTPStatus.OK, HTTPStatus.PARTIAL_CONTENT):
            text = (
                ""
                if answer.status == HTTPStatus.NOT_MODIFIED
                else f"{answer.status.phrase}: the file is {built.representation.size} bytes\n"
            )
            response = connection.respond(answer.status, text)
            if not text:
                del response.headers["Content-Type"], response.headers["Content-Length"]
            response.headers.update(answer.headers)
            return response
        if self._open() >= self.settings.max_sessions:
            return self._too_many(connection, "a file")
        self._admit(connection)
        head = connection.respond(answer.status, "")
        del head.headers["Content-Type"]
        head.headers["Content-Type"] = "application/octet-stream"
        head.headers.update(answer.headers)
        body = self._files.read(built, answer.offset, answer.length, self.metrics.file_bytes.inc)
        return streamed(head, body, self.settings.idle_timeout, length=answer.length)

    def _preflight(self, connection: GatedConnection, request: Request) -> Response:
        """The answer to an ``OPTIONS`` request: for a log's file, a CORS preflight's answer that lets the page
        of an allowed origin send its ranged, conditional GET; elsewhere no CORS."""
        response = connection.options()
        path = urlsplit(request.path).path
        if path.startswith(LOG_PATH) and _file_path(path) is not None:
            cors = self._cors(request)
            response.headers.update(cors)
            if "Access-Control-Allow-Origin" in cors:
                response.headers.update(
                    {
                        "Access-Control-Allow-Methods": ALLOW,
                        "Access-Control-Allow-Headers": FILE_REQUEST_HEADERS,
                        "Access-Control-Max-Age": str(PREFLIGHT_SECONDS),
                    }
                )
        return response

    def _cors(self, request: Request) -> dict[str, str]:
        """The CORS headers that let a page of another origin (the apps) read an answer: any origin, or those
        of ``--allowed-origin`` when set."""
        allowed = self.settings.allowed_origins
        origin = request.headers.get("Origin")
        if not allowed:
            return {"Access-Control-Allow-Origin": "*", "Access-Control-Expose-Headers": FILE_EXPOSED}
        if origin in allowed:
            return {
                "Access-Control-Allow-Origin": origin,
                "Access-Control-Expose-Headers": FILE_EXPOSED,
                "Vary": "Origin",
            }
        return {"Vary": "Origin"}

    def _too_many(self, connection: ServerConnection, what: str) -> Response:
        logger.warning("refused %s: %d sessions and exports open", what, self.settings.max_sessions)
        return connection.respond(HTTPStatus.SERVICE_UNAVAILABLE, "too many sessions, try again later\n")

    def _admit(self, connection: ServerConnection) -> None:
        """Count an export or file answer on ``connection`` in :meth:`_open` from now (its admission: call it with no
        await after the check) until its connection ends, whether or not its body is ever sent."""
        self._exporting.add(connection)
        connection.connection_lost_waiter.add_done_callback(lambda _: self._exporting.discard(connection))

    def _open(self) -> int:
        """Sessions and exports running now: what ``max_sessions`` bounds."""
        return len(self.sessions) + len(self._exporting)

    async def _listing(self, path: str, target: str) -> tuple[HTTPStatus, dict[str, Any]]:
        """The answer to ``GET /api/logs?...`` (a page of the catalog) or ``GET /api/logs/NAME`` (one log)."""
        if path.startswith(LOG_PATH):
            name = urllib.parse.unquote(path[len(LOG_PATH) :])
            try:
                check_log_name(name)
            except LogNotFound as exc:
                return HTTPStatus.NOT_FOUND, {"error": str(exc)}
            found = await self.indexer.one(name)
            if found is None:
                return HTTPStatus.NOT_FOUND, {"error": f"the catalog has no log named {name!r}"}
            return HTTPStatus.OK, found
        try:
            query = parse_query(urllib.parse.parse_qs(urlsplit(target).query, keep_blank_values=True))
        except QueryError as exc:
            return HTTPStatus.BAD_REQUEST, {"error": str(exc), "parameter": exc.parameter}
        body: dict[str, Any] = {"server": f"xviz-server {__version__}", **await self.indexer.page(query)}
        if query.first_page:  # no feed is connected before the server is ready
            body["live"] = [{"name": feed.name, "connected": feed.connected} for feed in self._live or ()]
        return HTTPStatus.OK, body

    def _viewer_refusal(self, connection: ServerConnection, request: Request) -> Response | None:
        """HTTP 401 when a viewer token is configured and the request does not give it."""
        if self.settings.viewer_token and not token_matches(request, self.settings.viewer_token):
            return connection.respond(
                HTTPStatus.UNAUTHORIZED, "this server needs a viewer token: ?token= or Authorization: Bearer\n"
            )
        return None


def _check_record_folder(root: Path) -> None:
    """Make ``--record``'s folder if missing and check that files can be written in it (it blocks).

    Raises :class:`~xviz_server.exceptions.ConfigError` saying what to
    change: recording into a folder that cannot be written would lose
    every update.
    """
    try:
        root.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=root):
            pass
    except OSError as exc:
        raise ConfigError(
            f"--record {root}: cannot write there ({exc.strerror or exc}): "
            "give a writable folder, or mount it read-write in a container"
        ) from None


def _import_session_modules() -> None:
    for name in SESSION_MODULES:
        importlib.import_module(f".{name}", __package__)


def _export_path(path: str) -> str | None:
    """The log an export URL names (see :func:`~xviz_server.foxglove.export.export_path`), or ``None``."""
    from .foxglove.export import export_path

    return export_path(path)


def _layout_path(path: str) -> str | None:
    """The log a layout URL names (see :func:`~xviz_server.foxglove.layout.layout_path`), or ``None``."""
    from .foxglove.layout import layout_path

    return layout_path(path)


def _file_path(path: str) -> str | None:
    """The log a file URL names (see :func:`~xviz_server.foxglove.seekable.file_path`), or ``None``."""
    from .foxglove.seekable import file_path

    return file_path(path)


def _broker(settings: Settings, live: LiveRegistry, metrics: Metrics, workers: Workers) -> Broker:
    """The broker of ``--broker``; raises :class:`~xviz_server.exceptions.ConfigError` without the ``broker`` extra."""
    assert settings.broker is not None
    try:
        from .live.broker import Broker
    except ImportError as exc:
        raise ConfigError(f"--broker needs the redis package ({exc}): pip install 'xviz-server[broker]'") from None
    return Broker(
        settings.broker,
        live,
        metrics,
        workers,
        ttl=settings.broker_ttl,
        max_bytes=int(settings.broker_max_mb * MB),
        max_update_bytes=int(settings.max_ingest_mb * MB),
    )


def parse_dataset(text: str) -> tuple[str, Path, dict[str, str]]:
    """``kitti:/data/drive`` as ``("kitti", Path("/data/drive"), {})``, ``demo`` as ``("demo", Path("demo"), {})``.

    Options of the kind follow the path as a query: ``rosbag:/data/drive.bag?config=map.toml``.
    Raises :class:`ValueError` for an unknown kind or option, or a path that does not exist.
    """
    kind, separator, rest = text.partition(":")
    path, _, query = rest.partition("?")
    if kind in GENERATED:
        return kind, Path(path or kind), {}
    if not separator or not kind or not path:
        raise ValueError(f"--dataset {text!r}: give KIND:PATH, like kitti:/data/2011_09_26_drive_0001_sync")
    if kind not in DATASET_KINDS:
        raise ValueError(f"--dataset {text!r}: unknown kind {kind!r}; known: {', '.join(sorted(DATASET_KINDS))}")
    if not Path(path).exists():
        raise ValueError(f"--dataset {text!r}: {path}: no such file or directory")
    options = dict(urllib.parse.parse_qsl(query))
    if unknown := sorted(options.keys() - dataset_options(kind)):
        raise ValueError(
            f"--dataset {text!r}: {kind} takes no option {', '.join(unknown)}; it takes: "
            f"{', '.join(sorted(dataset_options(kind))) or 'none'}"
        )
    return kind, Path(path), options


def _select_subprotocol(connection: ServerConnection, subprotocols: Sequence[Subprotocol]) -> Subprotocol | None:
    """The first Foxglove subprotocol the client offers; none (an XVIZ session) if it offers none."""
    return next((offered for offered in subprotocols if offered in SUBPROTOCOLS), None)


def _response(connection: ServerConnection, status: HTTPStatus, body: bytes, content_type: str) -> Response:
    response = connection.respond(status, "")
    del response.headers["Content-Type"], response.headers["Content-Length"]
    response.headers["Content-Type"] = content_type
    response.headers["Content-Length"] = str(len(body))
    return dataclasses.replace(response, body=body)


_LISTEN_HINTS = {
    errno.EADDRINUSE: "another process listens there: choose a free port with --port (XVIZ_PORT)",
    errno.EACCES: "ports below 1024 need privileges this process lacks: listen on a higher --port (XVIZ_PORT) "
    "and map the port you want to it",
    errno.EADDRNOTAVAIL: "no interface of this machine has that address: set --host (XVIZ_HOST), 0.0.0.0 for all",
}


def _is_loopback_host(host: str) -> bool:
    """Whether ``host`` (``--host``) is a loopback address or ``localhost``."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.split("%")[0]).is_loopback
    except ValueError:
        return False


def _cannot_listen(host: str, port: int, exc: OSError) -> str:
    """One sentence for an address the server cannot listen on, saying what to set."""
    reason = os.strerror(exc.errno).lower() if exc.errno else str(exc)
    hint = _LISTEN_HINTS.get(exc.errno or 0, "check --host and --port (XVIZ_HOST, XVIZ_PORT)")
    return f"cannot listen on {host}:{port}: {reason}; {hint}"


async def run(settings: Settings) -> None:
    """Serve until SIGINT or SIGTERM, then close every session and stop.

    Once the server listens, the objects made so far (modules, settings,
    the catalog) are frozen (:func:`gc.freeze`): the collector's full
    collections, which stop the event loop, then go over what serving made
    only, not the whole process. They are unfrozen when the server stops.
    """
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for signum in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(signum, stop.set)
    async with XVIZServer(settings):
        gc.freeze()
        try:
            await stop.wait()
        finally:
            gc.unfreeze()
        logger.info("shutting down: closing sessions")
