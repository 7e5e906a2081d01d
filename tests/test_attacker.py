"""The attacker's view, played against the real server on loopback: who may push a live feed,
what one message may cost, which feed a viewer gets."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import numpy as np
import pytest
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed, InvalidStatus

from helpers import PNG_2X1, client, eventually, metadata, running_server, update
from xviz_server.codec import Format, decode, edit_glb, encode
from xviz_server.live import feed as feed_module

META = metadata()


async def push_metadata(server, name: str, **kwargs):
    """A source that pushed the metadata of feed ``name``, once the feed has it."""
    source = await connect(f"ws://127.0.0.1:{server.port}/ingest/{name}", max_size=None, **kwargs)
    await source.send(json.dumps({"type": "xviz/metadata", "data": META}))
    for _ in range(200):
        feed = server.live.get(name)
        if feed is not None and feed.metadata is not None and feed.connected:
            return source
        await asyncio.sleep(0.025)
    raise AssertionError(f"feed {name!r} never got its metadata")


async def refused_with(source, message: bytes | str) -> str:
    await source.send(message)
    error = json.loads(await asyncio.wait_for(source.recv(), 10))
    assert error["type"] == "xviz/error"
    return error["data"]["message"]


async def test_a_web_page_cannot_push_a_live_feed_unless_its_origin_is_allowed():
    async with running_server(None) as server:
        with pytest.raises(InvalidStatus) as refused:
            await connect(f"ws://127.0.0.1:{server.port}/ingest/car", origin="http://evil.example")
        assert refused.value.response.status_code == 403
        assert b"browser pages may not push" in refused.value.response.body
        source = await push_metadata(server, "car")  # no Origin: a program, from loopback
        await source.close()
    async with running_server(None, allowed_origins=["https://ops.example"]) as server:
        source = await connect(f"ws://127.0.0.1:{server.port}/ingest/car", origin="https://ops.example")
        await source.close()


async def test_a_feed_named_explicitly_is_never_substituted():
    async with running_server(None) as server:
        evil = await push_metadata(server, "evil-from-browser")
        await evil.send(encode({"type": "xviz/state_update", "data": update(1.0)}, Format.BINARY))
        feed = server.live.get("evil-from-browser")
        await eventually(lambda: feed.state() is not None)  # the other feed has something to show
        async with client(server, "/?session_type=live&log=car") as viewer:
            notice = await viewer.recv()
            assert notice["type"] == "xviz/error" and "'car' has not started yet" in notice["data"]["message"]
            with pytest.raises(asyncio.TimeoutError):
                await viewer.recv(0.5)  # nothing of the other feed
        await evil.close()


async def test_a_feed_name_is_kept_for_its_source_then_a_takeover_starts_afresh(monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setattr(feed_module, "GRACE", 1.0)
    async with running_server(None) as server:
        first = await push_metadata(server, "car")
        await first.send(encode({"type": "xviz/state_update", "data": update(1.0)}, Format.BINARY))
        async with client(server, "/?session_type=live&log=car") as viewer:
            assert (await viewer.recv())["type"] == "xviz/metadata"
            assert (await viewer.recv())["data"]["updates"][0]["timestamp"] == 1.0
            await first.close()
            assert "went away" in (await viewer.recv())["data"]["message"]
            other = await connect(f"ws://127.0.0.1:{server.port}/ingest/car", local_addr=("127.0.0.2", 0))
            with pytest.raises(ConnectionClosed) as closed:
                await other.recv()
            assert "kept for its previous source" in closed.value.rcvd.reason
            await asyncio.sleep(1.2)  # the grace period ends
            thief = await push_metadata(server, "car", local_addr=("127.0.0.2", 0))
            again = await viewer.recv()
            assert again["type"] == "xviz/metadata"  # the same metadata, sent again: a new source
            await thief.close()


async def test_the_state_of_a_feed_whose_source_left_is_freed_after_the_grace_period(monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setattr(feed_module, "GRACE", 0.3)
    async with running_server(None) as server:
        source = await push_metadata(server, "car")
        await source.send(encode({"type": "xviz/state_update", "data": update(1.0, points=100_000)}, Format.BINARY))
        feed = server.live.get("car")
        assert feed is not None
        await eventually(lambda: feed.state() is not None)
        await source.close()
        await eventually(lambda: feed.state() is None)  # freed once the grace period is over


async def test_viewers_asking_for_made_up_feeds_create_nothing(monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setattr(feed_module.LiveRegistry, "MAX_WAITED", 20)
    async with running_server(None) as server:
        viewers = [await connect(f"ws://127.0.0.1:{server.port}/?session_type=live&log=made-up-{i}") for i in range(20)]
        for viewer in viewers:
            assert "has not started yet" in decode(await viewer.recv())["data"]["message"]
        async with client(server, "/?session_type=live&log=one-too-many") as late:
            messages = [await late.recv(), await late.recv()]
            assert any("too" in m["data"]["message"] or "no live feed" in m["data"]["message"] for m in messages)
        assert server.live.names() == []
        for viewer in viewers:
            await viewer.close()
        await eventually(lambda: not server.live._waited)  # nobody waits: the names are forgotten


@pytest.mark.parametrize("where", ["primitives", "behind a number"])
async def test_an_accessor_referenced_many_times_is_refused(where: str):
    cloud = np.zeros((50_000, 3), dtype=np.float32)  # 600 KB
    data = {
        "update_type": "SNAPSHOT",
        "updates": [{"timestamp": 1.0, "primitives": {"/points": {"points": [{"points": cloud}]}}}],
    }
    glb = encode({"type": "xviz/state_update", "data": data}, Format.BINARY)

    def reference_it_a_hundred_times(message):
        stream = message["data"]["updates"][0]["primitives"]["/points"]
        if where == "primitives":
            stream["points"] = stream["points"] * 100
        else:  # in a list of the update's own whose first item is a number, then the cloud's accessor 99 times
            message["data"]["updates"][0]["extra"] = [0, *[stream["points"][0]["points"]] * 99]
        return message

    amplified = edit_glb(glb, reference_it_a_hundred_times)
    assert len(amplified) < len(glb) + 5000
    async with running_server(None, max_ingest_mb=16) as server:
        source = await push_metadata(server, "car")
        problem = await refused_with(source, amplified)
        assert "expands to 57.2 MB when re-encoded" in problem
        await source.close()


async def test_millions_of_tiny_json_elements_are_refused_before_parsing():
    message = (
        b'{"type": "xviz/state_update", "data": {"update_type": "SNAPSHOT", "updates": [{"timestamp": 1, "x": ['
        + b"[]," * 2_100_000
        + b"[]]}]}}"
    )
    async with running_server(None) as server:
        source = await push_metadata(server, "car")
        problem = await refused_with(source, message)
        assert "more than 2000000 JSON lists and objects" in problem
        await source.close()


@pytest.mark.parametrize("name", ["x" * 300, "bad\x7fname", "c1\x85name", "a/" + "y" * 256])
async def test_feed_names_the_file_system_cannot_hold_are_refused_at_the_door(tmp_path: Path, name: str):
    async with running_server(None, record=tmp_path / "record") as server:
        with pytest.raises(InvalidStatus) as refused:
            await connect(f"ws://127.0.0.1:{server.port}/ingest/{name}")
        assert refused.value.response.status_code == 403 and b"bad feed name" in refused.value.response.body
        source = await push_metadata(server, "fine")  # the server goes on
        await source.close()


async def test_a_json_viewer_of_a_glb_feed_with_images_gets_every_update():
    meta = {**META, "streams": {**META["streams"], "/camera": {"category": "PRIMITIVE", "primitive_type": "IMAGE"}}}
    async with running_server(None) as server:
        feed = server.live.feed("car")
        feed.set_metadata(meta)
        async with client(server, "/?session_type=live&log=car&message_format=JSON") as viewer:
            assert (await viewer.recv())["type"] == "xviz/metadata"
            for i in range(5):
                data = update(float(i), points=20_000)
                data["updates"][0]["primitives"]["/camera"] = {
                    "images": [{"data": PNG_2X1, "width_px": 2, "height_px": 1}]
                }
                await feed.publish(encode({"type": "xviz/state_update", "data": data}, Format.BINARY))
                received = await viewer.recv(10)
                assert received["_text"] and received["data"]["updates"][0]["timestamp"] == float(i)
                assert received["data"]["updates"][0]["primitives"]["/camera"]["images"][0]["width_px"] == 2
