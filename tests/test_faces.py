"""The connection policy both protocol faces share (xviz_server/face.py), tested once for both.

Failures: an unexpected error while a session handles a message, or in the task that streams or plays a log, is
reported to the client and the session goes on. Measuring a link: sessions closing while their link is
sampled (under uvloop, the server's loop) leave no traceback in the server's log.
"""

from __future__ import annotations

import asyncio
import json
import random
from pathlib import Path
from typing import Any

import pytest
from test_foxglove import control, foxglove, next_of, opened
from websockets.asyncio.client import connect

from helpers import Client, client, http_get, running_server, served
from xviz_server.foxglove import connection as foxglove_connection
from xviz_server.foxglove.session import FoxgloveSession
from xviz_server.logs import Log
from xviz_server.xviz.session import Session

FACES = ("xviz", "foxglove")


class Fault(RuntimeError):
    """The unexpected error a test makes happen (a bug's stand-in: no real part raises it on purpose)."""


async def xviz_error(viewer: Client) -> str:
    message = await viewer.recv()
    assert message["type"] == "xviz/error", message
    return str(message["data"]["message"])


# -- the failure policy ----------------------------------------------------------


@pytest.mark.parametrize("face", FACES)
async def test_an_error_handling_a_message_is_reported_and_the_session_goes_on(
    kitti_root: Path, face: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    machine: Any = Session if face == "xviz" else FoxgloveSession
    receive = machine.receive

    def failing(self: Any, data: bytes | str) -> Any:
        if data == "fail":
            raise Fault("the session could not handle it")
        return receive(self, data)

    monkeypatch.setattr(machine, "receive", failing)
    async with running_server(kitti_root) as server:
        if face == "xviz":
            async with client(server, "/?log=kitti") as viewer:
                assert (await viewer.recv())["type"] == "xviz/metadata"
                await viewer.websocket.send("fail")
                text = await xviz_error(viewer)
                assert "internal server error while handling a message" in text and "Fault" in text
                await viewer.send("transform_log", {"id": "after"})
                assert (await viewer.until("transform_log_done", "after"))[0]["type"] == "xviz/state_update"
        else:
            async with await foxglove(server) as websocket:
                _, channels = await opened(websocket)
                await websocket.send("fail")
                status = await next_of(websocket, "status")
                assert status["level"] == 2 and "internal server error while handling a message" in status["message"]
                await websocket.send(
                    json.dumps({"op": "subscribe", "subscriptions": [{"id": 4, "channelId": channels[0]["id"]}]})
                )
                assert (await next_of(websocket, "message"))[0] == 4


@pytest.mark.parametrize("face", FACES)
async def test_an_error_while_sending_a_log_is_reported_and_the_next_request_is_served(
    kitti_root: Path, face: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The XVIZ face's stream and the Foxglove face's player fail once; the client is told, and served after."""
    failures = [Fault("reading the frame failed")]

    if face == "xviz":
        frame = Log.frame

        async def failing_frame(self: Log, *args: Any, **kwargs: Any) -> bytes:
            if failures:
                raise failures.pop()
            return await frame(self, *args, **kwargs)

        monkeypatch.setattr(Log, "frame", failing_frame)
    else:
        messages = foxglove_connection.frame_messages

        async def failing_messages(*args: Any) -> Any:
            if failures:
                raise failures.pop()
            return await messages(*args)

        monkeypatch.setattr(foxglove_connection, "frame_messages", failing_messages)
    async with running_server(kitti_root) as server:
        if face == "xviz":
            async with client(server, "/?log=kitti") as viewer:
                assert (await viewer.recv())["type"] == "xviz/metadata"
                await viewer.send("transform_log", {"id": "first"})
                text = await xviz_error(viewer)
                assert "internal server error while handling transform_log 'first'" in text and "Fault" in text
                assert (await viewer.recv())["type"] == "xviz/transform_log_done"
                await viewer.send("transform_log", {"id": "second"})
                assert len(await viewer.until("transform_log_done", "second")) == 26  # 25 frames, then the done
        else:
            async with await foxglove(server, subprotocols=["foxglove.sdk.v1"]) as websocket:
                info, channels = await opened(websocket)
                start = info["dataStartTime"]["sec"] * 1_000_000_000 + info["dataStartTime"]["nsec"]
                await websocket.send(
                    json.dumps({"op": "subscribe", "subscriptions": [{"id": 5, "channelId": channels[0]["id"]}]})
                )
                status = await next_of(websocket, "status")
                assert (
                    status["level"] == 2 and "internal server error while handling playing the log" in status["message"]
                )
                assert not failures
                await websocket.send(control(True, seek=start, request_id="again"))
                assert (await next_of(websocket, "state"))[4] == "again"
                assert (await next_of(websocket, "message"))[0] == 5


# -- measuring links -------------------------------------------------------------------


@pytest.mark.slow
async def test_sessions_closing_while_their_link_is_measured_leave_no_traceback(kitti_root: Path) -> None:
    """Issue 39, finding 6: uvloop's socket of a closed connection raised ValueError, which nothing caught."""
    rng = random.Random(6)

    async def session() -> None:
        # A cap makes even a loopback session measure its link (every 50 ms or so).
        async with client_of_path(port, "/?log=kitti&max_mbps=50") as websocket:
            await websocket.send(json.dumps({"type": "xviz/transform_log", "data": {"id": "all"}}))
            for _ in range(rng.randrange(1, 12)):
                await asyncio.wait_for(websocket.recv(), 30)
            websocket.transport.abort()  # gone at once, wherever the server's sampling is

    async with served(kitti_root) as server:
        port = server.port
        for _ in range(8):
            await asyncio.gather(*(session() for _ in range(8)), return_exceptions=True)
        status, _, body = await asyncio.to_thread(http_get, server.port, "/healthz")
        assert status == 200, body
        ended = "".join(server.lines).count("session end")
        log = "".join(server.lines)
    assert ended >= 60, f"only {ended} of 64 sessions ended"
    assert "Traceback" not in log and "negative file descriptor" not in log, log[-3000:]


def client_of_path(port: int, path: str) -> Any:
    """A client of the XVIZ face at ``path``."""
    return connect(f"ws://127.0.0.1:{port}{path}", max_size=None, open_timeout=30)
