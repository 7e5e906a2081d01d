"""Network ingest: a live source pushes its messages over a WebSocket.

A vehicle or simulator connects to ``/ingest/<name>`` and sends
``xviz/metadata``, then ``xviz/state_update`` messages (JSON or GLB), to the
live feed ``<name>``. With ``?reconfigure=1`` it declares that it accepts
configuration: the ``config_update`` of each viewer's ``xviz/reconfigure``
is then sent to it as an ``xviz/reconfigure`` message. A bad message gets an
``xviz/error`` back; the feed goes on.

Who may push is decided at the handshake (:func:`xviz_server.auth.ingest_refusal`).
"""

from __future__ import annotations

import logging
from typing import Any
from urllib.parse import parse_qsl, urlsplit

from websockets.asyncio.server import ServerConnection
from websockets.exceptions import ConnectionClosed
from websockets.frames import CloseCode

from ..auth import feed_name
from ..codec import decode, encode_json
from ..exceptions import DecodeError, MessageError, XVIZError
from .feed import LiveRegistry
from ..messages import Error, envelope, unwrap

__all__ = ["run_ingest"]

logger = logging.getLogger(__name__)

async def run_ingest(websocket: ServerConnection, live: LiveRegistry) -> None:
    """Feed the live feed named by the connection's path until the source leaves."""
    assert websocket.request is not None
    name = feed_name(websocket.request.path)
    assert name is not None
    feed = live.feed(name)
    if feed.connected:
        await websocket.close(CloseCode.POLICY_VIOLATION, f"live feed {name!r} already has a source")
        return
    accepts = dict(parse_qsl(urlsplit(websocket.request.path).query)).get("reconfigure") in ("1", "true")
    if accepts:
        async def forward(config_update: dict[str, Any]) -> None:
            await websocket.send(encode_json(envelope("reconfigure", {"update_type": "DELTA", "config_update": config_update})), text=True)

        feed.on_reconfigure = forward
    feed.connected = True
    logger.info("live source connected to %r from %s", name, websocket.remote_address)
    try:
        async for data in websocket:
            try:
                kind, content = unwrap(decode(data))
                if kind == "xviz/metadata":
                    feed.set_metadata(content)
                elif kind == "xviz/state_update":
                    await feed.publish(data if isinstance(data, bytes) else data.encode())
                else:
                    raise XVIZError(f"a live source sends xviz/metadata and xviz/state_update, not {kind!r}")
            except (DecodeError, MessageError, XVIZError) as exc:
                await websocket.send(encode_json(Error(message=f"live feed {name!r}: {str(exc).removeprefix(f'live feed {name!r}: ')}").to_envelope()), text=True)
    except ConnectionClosed:
        pass
    finally:
        feed.on_reconfigure = None
        feed.disconnect()
        logger.info("live source of %r went away", name)
