"""The session driver talks XVIZ to a server as streetscape.gl does.

A stand-in server replays the official KITTI GLB log the way the reference
Node server does: metadata on connect, then for each ``xviz/transform_log``
the frames in the requested window and an ``xviz/transform_log_done``. It
checks ``tests/interop/xviz-session.js`` and ``interop_session.py`` on their
own, independently of the project's server.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import pytest
from websockets.asyncio.server import ServerConnection, serve

from interop_session import run_xviz_session, run_xviz_session_async
from test_interop import xviz_decode

# The first three frames are 0.11 s and 0.1 s apart: a window of 0.25 s from
# the start holds all three, one of 0.15 s the first two.
WINDOW_OF_THREE = 0.25
WINDOW_OF_TWO = 0.15


class KittiReplay:
    """Serve a static GLB log; remember every request the client sent."""

    def __init__(self, log: Path) -> None:
        self.log = log
        index = json.loads((log / "0-frame.json").read_text())
        self.start_time: float = index["startTime"]
        self.timing: list[list[Any]] = index["timing"]
        self.requests: list[Any] = []

    @asynccontextmanager
    async def running(self) -> AsyncIterator[str]:
        """Serve on a free local port and yield the URL to connect to."""
        async with serve(self.handle, "127.0.0.1", 0) as server:
            port = server.sockets[0].getsockname()[1]
            yield f"ws://127.0.0.1:{port}/"

    async def handle(self, connection: ServerConnection) -> None:
        await connection.send(self.frame("1-frame"))
        async for message in connection:
            await self.answer(connection, message)

    async def answer(self, connection: ServerConnection, message: str | bytes) -> None:
        try:
            request = json.loads(message)
        except ValueError:
            await connection.send(envelope("error", message="malformed JSON"))
            return
        self.requests.append(request)
        if request.get("type") != "xviz/transform_log":
            await connection.send(envelope("error", message=f"unsupported {request.get('type')}"))
            return
        data = request["data"]
        for name in self.frames_between(data.get("start_timestamp"), data.get("end_timestamp")):
            await connection.send(self.frame(name))
        await connection.send(envelope("transform_log_done", id=data["id"]))

    def frames_between(self, start: float | None, end: float | None) -> list[str]:
        """The frames wholly inside [start, end]; a missing bound is open."""
        return [
            name
            for t_min, t_max, _, name in self.timing
            if (start is None or t_min >= start) and (end is None or t_max <= end)
        ]

    def timestamps_between(self, start: float, end: float) -> list[float]:
        return [t_min for t_min, t_max, _, _ in self.timing if t_min >= start and t_max <= end]

    def frame(self, name: str) -> bytes:
        return (self.log / f"{name}.glb").read_bytes()


def envelope(type_: str, **data: Any) -> str:
    return json.dumps({"type": f"xviz/{type_}", "data": data})


@pytest.fixture
def replay(kitti_log: Path) -> KittiReplay:
    return KittiReplay(kitti_log)


@pytest.fixture
async def url(replay: KittiReplay) -> AsyncIterator[str]:
    async with replay.running() as url:
        yield url


async def test_metadata_arrives_on_connect(kitti_log: Path, url: str):
    result = await run_xviz_session_async(url, [{"wait": "metadata"}])

    assert result.ok, result.stderr
    (metadata,) = result.messages
    assert metadata["kind"] == "binary"
    assert metadata["bytes"] == (kitti_log / "1-frame.glb").stat().st_size
    assert metadata["type"] == "xviz/metadata"
    assert metadata["raw"]["data"]["version"] == "2.0.0"
    parsed = metadata["parsed"]
    assert parsed["type"] == "METADATA" and parsed["version"] == "2.0.0"
    assert parsed["start_time"] == 1317042145.964
    assert result.summary == {
        "messages": 1,
        "by_type": {"xviz/metadata": 1},
        "errors": [],
        "closed": None,
    }


async def test_transform_log_is_answered_with_state_updates_then_done(
    kitti_log: Path, replay: KittiReplay, url: str
):
    start = replay.start_time
    request = {
        "type": "xviz/transform_log",
        "data": {"id": "1", "start_timestamp": start, "end_timestamp": start + WINDOW_OF_TWO},
    }
    script = [{"wait": "metadata"}, {"send": request}, {"wait": "done", "id": "1"}, {"close": True}]
    result = await run_xviz_session_async(url, script)

    assert result.ok, result.stderr
    assert replay.requests == [request]
    assert [message["type"] for message in result.messages] == [
        "xviz/metadata",
        "xviz/state_update",
        "xviz/state_update",
        "xviz/transform_log_done",
    ]
    # Over the socket the client reads the frames exactly as it reads the files.
    files = xviz_decode([kitti_log / f"{number}-frame.glb" for number in (1, 2, 3)])
    for message, file in zip(result.messages, files):
        assert message["kind"] == "binary"
        assert (message["raw"], message["parsed"]) == (file["raw"], file["parsed"])
    done = result.messages[-1]
    assert done["kind"] == "text"
    assert done["raw"] == {"type": "xviz/transform_log_done", "data": {"id": "1"}}
    assert done["parsed"] == {"id": "1", "type": "DONE"}
    assert result.summary == {
        "messages": 4,
        "by_type": {"xviz/metadata": 1, "xviz/state_update": 2, "xviz/transform_log_done": 1},
        "errors": [],
        "closed": {"code": 1000, "reason": ""},
    }


async def test_transform_log_window_is_placed_from_the_metadata_start_time(
    replay: KittiReplay, url: str
):
    script = [
        {"wait": "metadata"},
        {"send_transform_log": {"id": "a", "from_start": 0.0, "to_start": WINDOW_OF_THREE}},
        {"wait": "done", "id": "a"},
        {"send_transform_log": {"id": "b", "to_start": WINDOW_OF_TWO}},
        {"wait": "done", "id": "b"},
    ]
    result = await run_xviz_session_async(url, script)

    assert result.ok, result.stderr
    start = replay.start_time
    first, second = (request["data"] for request in replay.requests)
    assert first == {
        "id": "a",
        "start_timestamp": start,
        "end_timestamp": pytest.approx(start + WINDOW_OF_THREE),
    }
    assert second == {"id": "b", "end_timestamp": pytest.approx(start + WINDOW_OF_TWO)}
    timestamps = [update["parsed"]["timestamp"] for update in result.of_type("xviz/state_update")]
    assert timestamps == (
        replay.timestamps_between(start, start + WINDOW_OF_THREE)
        + replay.timestamps_between(start, start + WINDOW_OF_TWO)
    )
    assert len(timestamps) == 5


async def test_a_wait_that_times_out_fails_and_says_what_it_waited_for(url: str):
    script = [
        {"wait": "metadata"},
        {"send_transform_log": {"id": "1", "from_start": 0.0, "to_start": WINDOW_OF_TWO}},
        {"wait": "done", "id": "2", "timeout_ms": 500},
        {"close": True},
    ]
    result = await run_xviz_session_async(url, script)

    assert result.returncode == 1
    reason = (
        'step 3 {"wait":"done","id":"2","timeout_ms":500}: timed out after 500 ms waiting for '
        'xviz/transform_log_done with id "2"; received 4 message(s): 1 xviz/metadata, '
        '2 xviz/state_update, 1 xviz/transform_log_done; transform_log_done ids ["1"]'
    )
    assert result.stderr == f"xviz-session: {reason}\n"
    # What arrived before the failure is still reported.
    assert [message["type"] for message in result.messages] == [
        "xviz/metadata",
        "xviz/state_update",
        "xviz/state_update",
        "xviz/transform_log_done",
    ]
    assert result.summary is not None
    assert result.summary["errors"] == [{"source": "script", "message": reason}]
    assert result.summary["closed"] is None


async def test_brief_mode_details_only_metadata_errors_and_done(replay: KittiReplay, url: str):
    script = [
        {"wait": "metadata"},
        {"send_transform_log": {"id": "1", "from_start": 0.0, "to_start": WINDOW_OF_THREE}},
        {"wait": "done", "id": "1"},
        {"send": "not JSON"},
        {"wait": "error"},
    ]
    result = await run_xviz_session_async(url, script, brief=True)

    assert result.ok, result.stderr
    metadata, *updates, done, error = result.messages
    assert metadata["parsed"]["type"] == "METADATA"
    assert done["parsed"] == {"id": "1", "type": "DONE"}
    assert error["kind"] == "text"
    assert error["raw"] == {"type": "xviz/error", "data": {"message": "malformed JSON"}}
    assert error["parsed"]["type"] == "ERROR"
    start = replay.start_time
    assert [update["timestamp"] for update in updates] == replay.timestamps_between(
        start, start + WINDOW_OF_THREE
    )
    for update in updates:
        assert update.keys() == {"index", "kind", "bytes", "type", "timestamp", "streams", "poses"}
        assert "/lidar/points" in update["streams"]
        assert update["poses"] == ["/vehicle_pose"]
    assert result.summary is not None
    assert result.summary["errors"] == [
        {"index": error["index"], "source": "server", "message": "malformed JSON"}
    ]


async def test_the_blocking_helper_runs_the_same_session(url: str):
    result = await asyncio.to_thread(run_xviz_session, url, [{"wait": "metadata"}])

    assert result.ok, result.stderr
    assert [message["type"] for message in result.messages] == ["xviz/metadata"]


async def test_a_bad_script_is_refused_before_connecting(url: str):
    result = await run_xviz_session_async(url, [{"wait": "metadata"}, {"wait": "sunrise"}])

    assert result.returncode == 2
    assert 'unknown wait "sunrise"' in result.stderr
    assert (result.messages, result.summary) == ([], None)
