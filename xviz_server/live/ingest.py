"""Network ingest: a live source pushes its messages over a WebSocket.

A vehicle or simulator connects to ``/ingest/<name>`` and sends
``xviz/metadata``, then ``xviz/state_update`` messages (JSON or GLB), to the
live feed ``<name>``. With ``?reconfigure=1`` it declares that it accepts
configuration: the ``config_update`` of each viewer's ``xviz/reconfigure``
is then sent to it as an ``xviz/reconfigure`` message.

Who may push is decided at the handshake (:func:`xviz_server.auth.ingest_refusal`),
and whether a source may take a feed's name by :meth:`LiveFeed.claim`. Every
message is checked at the door (:func:`xviz_server.admission.admit`: large
JSON in a worker process); a bad one gets an ``xviz/error`` naming the field
and reaches no viewer, and the source stays connected.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any
from urllib.parse import parse_qsl, urlsplit

from websockets.asyncio.server import ServerConnection
from websockets.exceptions import ConnectionClosed
from websockets.frames import CloseCode

from ..admission import admit
from ..auth import feed_name
from ..codec import decode, encode_json
from ..exceptions import MessageError, XVIZError
from ..flow import close, watch_progress
from ..messages import Error, envelope, unwrap
from ..metrics import Metrics
from ..settings import Settings
from ..work import Workers
from .feed import LiveRegistry

__all__ = ["run_ingest"]

logger = logging.getLogger(__name__)

#: JSON messages larger than this are checked and parsed in a worker process, off the event loop.
LARGE_JSON = 256 * 1024


async def run_ingest(
    websocket: ServerConnection, live: LiveRegistry, workers: Workers, settings: Settings, metrics: Metrics
) -> None:
    """Feed the live feed named by the connection's path until the source leaves."""
    assert websocket.request is not None
    name = feed_name(websocket.request.path)
    assert name is not None
    address = websocket.remote_address
    source = str(address[0]) if address else "?"
    feed = live.feed(name)
    try:
        await live.claim(feed, source)
    except XVIZError as exc:
        if feed.metadata is None and not feed.connected:
            live.drop(feed)
        await close(websocket, CloseCode.POLICY_VIOLATION, str(exc)[:120])
        return
    if dict(parse_qsl(urlsplit(websocket.request.path).query)).get("reconfigure") in ("1", "true"):

        async def forward(config_update: dict[str, Any]) -> None:
            reconfigure = envelope("reconfigure", {"update_type": "DELTA", "config_update": config_update})
            await websocket.send(encode_json(reconfigure), text=True)

        feed.on_reconfigure = forward
    feed.connected = True
    logger.info("live source connected to %r from %s", name, address)
    limit = int(settings.max_ingest_mb * 2**20)
    watchdog = asyncio.ensure_future(watch_progress(websocket, settings.idle_timeout))
    try:
        async for data in websocket:
            raw = data.encode() if isinstance(data, str) else data
            run = workers.io
            if len(raw) > LARGE_JSON and raw[:4] != b"glTF":
                await workers.warm()  # not the stand-in thread: parsing holds the GIL for seconds
                run = workers.cpu
            try:
                kind, glb = await run(admit, raw, limit)
                if kind == "xviz/metadata":
                    feed.set_metadata(unwrap(decode(glb))[1])
                else:
                    await feed.publish(glb)
            except MessageError as exc:  # refused at the door
                problem = f"live feed {name!r}: {exc}"
            except XVIZError as exc:  # refused by the feed, which names itself
                problem = str(exc)
            else:
                continue
            metrics.ingest_refused.inc()
            await websocket.send(encode_json(Error(message=problem).to_envelope()), text=True)
    except ConnectionClosed:
        pass
    finally:
        watchdog.cancel()
        feed.on_reconfigure = None
        feed.disconnect()
        logger.info("live source of %r went away", name)
