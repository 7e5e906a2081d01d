"""Test helpers: logs written in the reference layout, a running server, a client."""

from __future__ import annotations

import asyncio
import contextlib
import json
from pathlib import Path
from typing import Any, AsyncIterator

import numpy as np
from websockets.asyncio.client import ClientConnection, connect

from xviz_server.codec import Format, decode, encode
from xviz_server.server import XVIZServer
from xviz_server.settings import Settings


def metadata(streams: dict[str, dict] | None = None, **log_info: float) -> dict[str, Any]:
    data: dict[str, Any] = {
        "version": "2.0.0",
        "streams": streams
        or {
            "/vehicle_pose": {"category": "POSE"},
            "/points": {"category": "PRIMITIVE", "primitive_type": "POINT"},
            "/speed": {"category": "TIME_SERIES", "scalar_type": "FLOAT"},
        },
    }
    if log_info:
        data["log_info"] = log_info
    return data


def update(t: float, *, points: int = 10, update_type: str = "SNAPSHOT", streams: tuple[str, ...] = ("/vehicle_pose", "/points", "/speed")) -> dict[str, Any]:
    """A state update at time ``t`` carrying some of three streams."""
    stream_set: dict[str, Any] = {"timestamp": t}
    if "/vehicle_pose" in streams:
        stream_set["poses"] = {"/vehicle_pose": {"timestamp": t, "position": [t, 0.0, 0.0], "orientation": [0.0, 0.0, 0.0]}}
    if "/points" in streams:
        cloud = np.full((points, 3), t, dtype=np.float32)
        stream_set["primitives"] = {"/points": {"points": [{"points": cloud}]}}
    if "/speed" in streams:
        stream_set["time_series"] = [{"timestamp": t, "streams": ["/speed"], "values": {"doubles": [t * 2]}}]
    return {"update_type": update_type, "updates": [stream_set]}


def write_log(
    directory: Path,
    updates: list[dict[str, Any]],
    *,
    fmt: Format = Format.BINARY,
    meta: dict[str, Any] | None = None,
    index: bool = True,
) -> Path:
    """Write a log directory in the reference layout; return it."""
    directory.mkdir(parents=True, exist_ok=True)
    (directory / f"1-frame{fmt.suffix}").write_bytes(encode({"type": "xviz/metadata", "data": meta or metadata()}, fmt))
    timing = []
    for i, data in enumerate(updates):
        (directory / f"{i + 2}-frame{fmt.suffix}").write_bytes(encode({"type": "xviz/state_update", "data": data}, fmt))
        times = [u["timestamp"] for u in data["updates"]]
        timing.append([min(times), max(times), i, f"{i + 2}-frame"])
    if index:
        document = {"startTime": timing[0][0], "endTime": timing[-1][1], "timing": timing}
        (directory / "0-frame.json").write_text(json.dumps(document))
    return directory


def ten_hz(count: int, start: float = 100.0, **kwargs: Any) -> list[dict[str, Any]]:
    return [update(round(start + i / 10, 3), **kwargs) for i in range(count)]


@contextlib.asynccontextmanager
async def running_server(data_dir: Path, **settings: Any) -> AsyncIterator[XVIZServer]:
    """An XVIZ server on a free loopback port."""
    async with XVIZServer(Settings(host="127.0.0.1", port=0, **settings), data_dir) as server:
        yield server


class Client:
    """A scripted XVIZ client over a real WebSocket."""

    def __init__(self, websocket: ClientConnection) -> None:
        self.websocket = websocket

    async def recv(self, timeout: float = 10) -> dict[str, Any]:
        """The next message, decoded; ``_text`` tells whether it came as a text frame."""
        data = await asyncio.wait_for(self.websocket.recv(), timeout)
        message = decode(data)
        message["_text"] = isinstance(data, str)
        message["_bytes"] = len(data)
        return message

    async def send(self, kind: str, data: Any) -> None:
        await self.websocket.send(json.dumps({"type": f"xviz/{kind}", "data": data}))

    async def until(self, kind: str, request_id: str | None = None, timeout: float = 30) -> list[dict[str, Any]]:
        """Messages up to and including the first of type ``xviz/<kind>`` (with ``request_id``)."""
        received = []
        while True:
            message = await self.recv(timeout)
            received.append(message)
            if message["type"] == f"xviz/{kind}" and (request_id is None or message["data"].get("id") == request_id):
                return received


@contextlib.asynccontextmanager
async def client(server: XVIZServer, path: str = "/", **kwargs: Any) -> AsyncIterator[Client]:
    async with connect(f"ws://127.0.0.1:{server.port}{path}", max_size=None, **kwargs) as websocket:
        yield Client(websocket)


def timestamps(messages: list[dict[str, Any]]) -> list[float]:
    """Timestamps of the state updates among ``messages``."""
    return [m["data"]["updates"][0]["timestamp"] for m in messages if m["type"] == "xviz/state_update"]
