"""A real session against the running server, through the published client.

The node driver (tests/interop/xviz-session.js) talks to our server the way
streetscape.gl does and decodes everything with @xviz/parser 1.0.13; what it
makes of the streamed frames must be what it makes of the original files.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import uvloop

from helpers import assert_same_parse, run_xviz_session_async, running_server, xviz_decode


@pytest.fixture(scope="module")
def originals(kitti_log: Path) -> dict[float, dict]:
    """The client's parse of every original KITTI frame, by timestamp."""
    files = [kitti_log / "1-frame.glb"] + [kitti_log / f"{i}-frame.glb" for i in range(2, 27)]
    return {line["parsed"]["timestamp"]: line["parsed"] for line in xviz_decode(files)[1:]}


SESSION = [
    {"wait": "metadata"},
    {"send_transform_log": {"id": "0", "from_start": -1}},  # the whole log, as XVIZStreamLoader asks
    {"wait": "done", "id": "0"},
    {"send": {"type": "xviz/transform_point_in_time", "data": {"id": "p", "query_timestamp": {"$timestamp": 1.05}}}},
    {"wait": "state_updates", "count": 26},
    {
        "send_transform_log": {
            "id": "1",
            "from_start": 0.5,
            "to_start": 1.45,
            "desired_streams": ["/vehicle_pose", "/lidar/points"],
        }
    },
    {"wait": "done", "id": "1"},
    {"close": True},
]


@pytest.mark.slow
@pytest.mark.parametrize("fmt", ["BINARY", "JSON"])
async def test_streetscape_client_session(kitti_root: Path, originals: dict[float, dict], fmt: str):
    await streetscape_session(kitti_root, originals, fmt)


@pytest.mark.slow
@pytest.mark.parametrize("fmt", ["BINARY", "JSON"])
def test_streetscape_client_session_on_uvloop(kitti_root: Path, originals: dict[float, dict], fmt: str):
    """The same session on the event loop the server runs on (frames leave through the transport's writev)."""
    uvloop.run(streetscape_session(kitti_root, originals, fmt))


async def streetscape_session(kitti_root: Path, originals: dict[float, dict], fmt: str) -> None:
    async with running_server(kitti_root) as server:
        url = f"ws://127.0.0.1:{server.port}/?log=kitti&worker=true&profile=default&message_format={fmt}"
        result = await run_xviz_session_async(url, SESSION, timeout=180)
    assert result.ok, result.stderr
    assert result.summary["errors"] == []
    assert result.summary["closed"]["code"] == 1000

    kinds = [m["type"] for m in result.messages]
    assert kinds[0] == "xviz/metadata"
    metadata = result.messages[0]["parsed"]
    assert metadata["version"] == "2.0.0" and metadata["start_time"] == 1317042145.964
    assert all(m["kind"] == ("text" if fmt == "JSON" else "binary") for m in result.messages)

    updates = result.of_type("xviz/state_update")
    whole_log, instant, filtered = updates[:25], updates[25], updates[26:]
    assert [u["parsed"]["timestamp"] for u in whole_log] == sorted(originals)
    for update in whole_log:
        expected = originals[update["parsed"]["timestamp"]]
        if fmt == "BINARY":
            assert update["parsed"] == expected
        else:
            assert_same_parse(update["parsed"], expected, str(update["parsed"]["timestamp"]))

    # point in time: the complete state of the last frame at or before start + 1.05
    assert instant["raw"]["data"]["update_type"] == "COMPLETE_STATE"
    frame_time = max(t for t in originals if t <= 1317042145.964 + 1.05)
    assert instant["parsed"]["timestamp"] == frame_time
    assert instant["parsed"]["streams"]["/lidar/points"] == originals[frame_time]["streams"]["/lidar/points"]

    # filtered request: only the two streams, in the window
    times = [u["parsed"]["timestamp"] for u in filtered]
    assert times == [t for t in sorted(originals) if 1317042145.964 + 0.5 <= t <= 1317042145.964 + 1.45]
    for update in filtered:
        assert set(update["parsed"]["streams"]) == {"/lidar/points"}
        assert set(update["parsed"]["poses"]) == {"/vehicle_pose"}
        expected = originals[update["parsed"]["timestamp"]]["streams"]["/lidar/points"]["pointCloud"]
        assert update["parsed"]["streams"]["/lidar/points"]["pointCloud"]["positions"] == expected["positions"]
    dones = [m["raw"]["data"]["id"] for m in result.of_type("xviz/transform_log_done")]
    assert dones == ["0", "1"]
