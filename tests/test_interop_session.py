"""The published client's session driver against the product: a session as streetscape.gl runs it.

``tests/interop/xviz-session.js`` connects with the ``ws`` package, performs a
script of client actions and decodes every message with @xviz/parser 1.0.13;
here it talks to the real server serving the official KITTI GLB log, and what
the client makes of each frame is compared with what it makes of the file.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

from helpers import run_xviz_session, run_xviz_session_async, running_server, xviz_decode

# The first three frames are 0.11 s and 0.1 s apart: a window of 0.25 s from
# the start holds all three, one of 0.15 s the first two.
WINDOW_OF_THREE = 0.25
WINDOW_OF_TWO = 0.15


@pytest.fixture
def timing(kitti_log: Path) -> list[list[Any]]:
    return json.loads((kitti_log / "0-frame.json").read_text())["timing"]


@pytest.fixture
async def url(kitti_log: Path) -> AsyncIterator[str]:
    async with running_server(kitti_log) as server:
        yield f"ws://127.0.0.1:{server.port}/?log={kitti_log.name}"


def timestamps_between(timing: list[list[Any]], start: float, end: float) -> list[float]:
    return [t_min for t_min, t_max, _, _ in timing if t_min >= start and t_max <= end]


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


async def test_transform_log_is_answered_with_state_updates_then_done(kitti_log: Path, timing: list, url: str):
    start = timing[0][0]
    request = {
        "type": "xviz/transform_log",
        "data": {"id": "1", "start_timestamp": start, "end_timestamp": start + WINDOW_OF_TWO},
    }
    script = [{"wait": "metadata"}, {"send": request}, {"wait": "done", "id": "1"}, {"close": True}]
    result = await run_xviz_session_async(url, script)

    assert result.ok, result.stderr
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
    assert done["kind"] == "binary"  # in the session's format: the log's own, GLB
    assert done["raw"] == {"type": "xviz/transform_log_done", "data": {"id": "1"}}
    assert done["parsed"] == {"id": "1", "type": "DONE"}
    assert result.summary == {
        "messages": 4,
        "by_type": {"xviz/metadata": 1, "xviz/state_update": 2, "xviz/transform_log_done": 1},
        "errors": [],
        "closed": {"code": 1000, "reason": ""},
    }


async def test_transform_log_window_is_placed_from_the_metadata_start_time(timing: list, url: str):
    script = [
        {"wait": "metadata"},
        {"send_transform_log": {"id": "a", "from_start": 0.0, "to_start": WINDOW_OF_THREE}},
        {"wait": "done", "id": "a"},
        {"send_transform_log": {"id": "b", "to_start": WINDOW_OF_TWO}},
        {"wait": "done", "id": "b"},
    ]
    result = await run_xviz_session_async(url, script)

    assert result.ok, result.stderr
    start = timing[0][0]
    timestamps = [update["parsed"]["timestamp"] for update in result.of_type("xviz/state_update")]
    assert timestamps == (
        timestamps_between(timing, start, start + WINDOW_OF_THREE)
        + timestamps_between(timing, start, start + WINDOW_OF_TWO)
    )
    assert len(timestamps) == 5


async def test_a_wait_that_times_out_fails_and_says_what_it_waited_for(url: str):
    script = [
        {"wait": "metadata"},
        {"send_transform_log": {"id": "1", "from_start": 0.0, "to_start": WINDOW_OF_TWO}},
        {"wait": "done", "id": "1"},  # all that comes has come: the timeout below races nothing
        {"wait": "done", "id": "2", "timeout_ms": 500},
        {"close": True},
    ]
    result = await run_xviz_session_async(url, script)

    assert result.returncode == 1
    reason = (
        'step 4 {"wait":"done","id":"2","timeout_ms":500}: timed out after 500 ms waiting for '
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


async def test_brief_mode_details_only_metadata_errors_and_done(timing: list, url: str):
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
    assert error["kind"] == "binary"  # in the session's format, the log's own: GLB
    message = error["raw"]["data"]["message"]
    assert error["raw"]["type"] == "xviz/error" and message.startswith("malformed message")
    assert error["parsed"]["type"] == "ERROR"
    start = timing[0][0]
    assert [update["timestamp"] for update in updates] == timestamps_between(timing, start, start + WINDOW_OF_THREE)
    for update in updates:
        assert update.keys() == {"index", "kind", "bytes", "type", "timestamp", "streams", "poses"}
        assert "/lidar/points" in update["streams"]
        assert update["poses"] == ["/vehicle_pose"]
    assert result.summary is not None
    assert result.summary["errors"] == [{"index": error["index"], "source": "server", "message": message}]


async def test_the_blocking_helper_runs_the_same_session(url: str):
    result = await asyncio.to_thread(run_xviz_session, url, [{"wait": "metadata"}])

    assert result.ok, result.stderr
    assert [message["type"] for message in result.messages] == ["xviz/metadata"]


async def test_a_bad_script_is_refused_before_connecting(url: str):
    result = await run_xviz_session_async(url, [{"wait": "metadata"}, {"wait": "sunrise"}])

    assert result.returncode == 2
    assert 'unknown wait "sunrise"' in result.stderr
    assert (result.messages, result.summary) == ([], None)
