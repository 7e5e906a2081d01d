"""What the Foxglove and Lichtblick apps need beyond the protocol: schemas their parsers take, the time before the
messages it stamps, and poses that move the vehicle in ``map`` (the real app itself: test_lichtblick.py)."""

from __future__ import annotations

import asyncio
import json
import math
import struct
from pathlib import Path
from typing import Any

import pytest
from test_foxglove import foxglove_subscribed, kitti_source, opened
from websockets.asyncio.client import connect

from helpers import foxglove_client, http_get, running_server
from xviz_server.builder import FrameBuilder, MetadataBuilder
from xviz_server.codec import Format, decode, encode
from xviz_server.foxglove.translate import plan, read_survey, survey
from xviz_server.messages import envelope

#: The JSON types a property may have in Foxglove's and Lichtblick's JSON Schema parser (``parseJsonSchema``):
#: one, as a string; ``oneOf`` only of numeric constants.
_PARSED_TYPES = {"boolean", "string", "number", "integer", "object", "array"}


def parser_problems(schema: dict[str, Any], where: str = "") -> list[str]:
    """Why the apps' parser would drop a channel of this JSON Schema: the rules its parser applies, property by property."""
    if schema.get("type") != "object":
        return [f"{where or 'root'}: not an object"]
    problems = []
    for name, field in (schema.get("properties") or {}).items():
        path = f"{where}.{name}".lstrip(".")
        if "oneOf" in field:
            if not all(isinstance(item.get("const"), (int, float)) for item in field["oneOf"]):
                problems.append(f"{path}: oneOf of non-numbers")
        elif field.get("type") not in _PARSED_TYPES:
            problems.append(f"{path}: type {field.get('type')!r}")
        elif field["type"] == "object":
            problems += parser_problems(field, path)
        elif field["type"] == "array" and (field.get("items") or {}).get("type") not in _PARSED_TYPES:
            problems.append(f"{path}: array items {field.get('items')!r}")
    return problems


def kitti_updates(kitti_log: Path) -> list[dict[str, Any]]:
    frames = sorted(kitti_log.glob("*-frame.glb"), key=lambda path: int(path.name.split("-")[0]))[1:]
    return [decode(path.read_bytes())["data"]["updates"][0] for path in frames]


def haversine(a: dict[str, float], b: dict[str, float]) -> float:
    """Metres between two map origins on a sphere of the earth's mean radius (not the server's formula)."""
    p1, p2 = math.radians(a["latitude"]), math.radians(b["latitude"])
    dp, dl = p2 - p1, math.radians(b["longitude"] - a["longitude"])
    h = math.sin(dp / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(dl / 2) ** 2
    return 2 * 6371008.8 * math.asin(math.sqrt(h))


async def test_every_advertised_json_schema_has_one_type_per_property(kitti_root: Path) -> None:
    async with running_server(kitti_root) as server:
        out = await foxglove_client(f"ws://127.0.0.1:{server.port}/?log=kitti", "foxglove.websocket.v1")
        async with connect(f"ws://127.0.0.1:{server.port}/?log=kitti", subprotocols=["foxglove.websocket.v1"]) as ws:  # type: ignore[list-item]
            _, advertised = await opened(ws)
    json_schemas = {c["topic"]: json.loads(c["schema"]) for c in advertised if c["schemaEncoding"] == "jsonschema"}
    assert "/vehicle/velocity" in json_schemas
    assert {topic: parser_problems(schema) for topic, schema in json_schemas.items()} == {
        topic: [] for topic in json_schemas
    }
    assert json_schemas["/vehicle/velocity"]["properties"]["value"] == {"type": "number"}
    # Each time series message is {"timestamp", "value"}, as a Plot panel reads it.
    assert {tuple(keys) for keys in out["topics"]["/vehicle/velocity"]["summaries"]} == {("timestamp", "value")}


def test_a_time_series_without_a_scalar_type_takes_its_first_value_s_type() -> None:
    meta = MetadataBuilder().pose("/vehicle_pose")
    meta.time_series("/state", "STRING").time_series("/engaged", "BOOL").time_series("/speed", "FLOAT")
    frame = FrameBuilder(meta.build())
    frame.pose("/vehicle_pose", 10.0, map_origin=(8.43, 49.01, 116.4))
    frame.time_series("/state", 10.0, "autonomous").time_series("/engaged", 10.0, True).time_series("/speed", 10.0, 3.5)
    found = read_survey(survey(encode(envelope("state_update", frame.build()), Format.JSON)))
    assert found.origin == (8.43, 49.01, 116.4)
    assert found.values == {"/state": "string", "/engaged": "boolean", "/speed": "number"}
    metadata = {"streams": {name: {"category": "TIME_SERIES"} for name in found.values}}
    metadata["streams"]["/count"] = {"category": "TIME_SERIES", "scalar_type": "INT32"}
    channels = {c.topic: json.loads(c.schema.schema) for c in plan(metadata, first=found).channels}
    assert {topic: schema["properties"]["value"] for topic, schema in channels.items()} == {
        "/state": {"type": "string"},
        "/engaged": {"type": "boolean"},
        "/speed": {"type": "number"},
        "/count": {"type": "integer"},
    }
    assert all(parser_problems(schema) == [] for schema in channels.values())


async def test_the_time_comes_before_the_messages_it_stamps_with_their_xviz_timestamp(
    kitti_root: Path, kitti_log: Path
) -> None:
    """The apps stamp a message with the last time message: each must be the message's own XVIZ timestamp."""
    expected = [round(update["timestamp"] * 1e9) for update in kitti_updates(kitti_log)]
    stamped: dict[int, list[int]] = {}
    payloads: dict[int, list[bytes]] = {}
    async with running_server(kitti_root) as server:
        async with connect(
            f"ws://127.0.0.1:{server.port}/?log=kitti", subprotocols=["foxglove.websocket.v1"], max_size=None
        ) as ws:  # type: ignore[list-item]
            _, channels = await opened(ws)
            await ws.send(
                json.dumps(
                    {"op": "subscribe", "subscriptions": [{"id": c["id"], "channelId": c["id"]} for c in channels]}
                )
            )
            clock: int | None = None
            times: list[int] = []
            while len(times) < len(expected):
                data = await asyncio.wait_for(ws.recv(), 30)
                if isinstance(data, str):
                    continue
                if data[0] == 0x02:  # time
                    clock = struct.unpack_from("<Q", data, 1)[0]
                    times.append(clock)
                elif data[0] == 0x01:  # message data: the app's receive time is the clock
                    subscription, log_time = struct.unpack_from("<IQ", data, 1)
                    assert clock == log_time, (subscription, clock, log_time)
                    stamped.setdefault(subscription, []).append(clock)
                    payloads.setdefault(subscription, []).append(data[13:])
    assert times == expected
    # Every channel with data in every frame got it at that frame's time.
    velocity = next(c["id"] for c in channels if c["topic"] == "/vehicle/velocity")
    points = next(c["id"] for c in channels if c["topic"] == "/lidar/points")
    assert (
        stamped[velocity] == expected[: len(stamped[velocity])] and stamped[points] == expected[: len(stamped[points])]
    )
    assert len(stamped[velocity]) >= len(expected) - 1
    # The time series' own timestamp is the XVIZ one, its value a number.
    values = [json.loads(payload) for payload in payloads[velocity]]
    assert [round(v["timestamp"] * 1e9) for v in values] == stamped[velocity]
    assert all(isinstance(v["value"], float) for v in values)


async def test_the_vehicle_moves_in_map_by_its_map_origin(kitti_root: Path, kitti_log: Path) -> None:
    updates = kitti_updates(kitti_log)
    origins = [update["poses"]["/vehicle_pose"]["map_origin"] for update in updates]
    async with running_server(kitti_root) as server:
        url, options = f"ws://127.0.0.1:{server.port}/?log=kitti", ("--times", str(len(updates)))  # to the last frame
        out = await foxglove_client(url, "foxglove.websocket.v1", options=options)
    # protobufjs leaves a field at its default (0) out
    translations = [
        {k: t["translation"].get(k, 0.0) for k in "xyz"} for t in out["topics"]["/vehicle_pose"]["summaries"]
    ]
    poses = out["topics"]["/vehicle_pose/pose"]["summaries"]
    assert len(translations) == len(updates)
    first = translations[0]
    assert math.hypot(first["x"], first["y"]) < 1e-6  # map's origin is the log's first map_origin
    for translation, origin in zip(translations, origins):
        travelled = math.hypot(translation["x"], translation["y"])
        assert travelled == pytest.approx(haversine(origins[0], origin), rel=0.01, abs=0.05)
    assert math.hypot(translations[-1]["x"], translations[-1]["y"]) > 5  # this excerpt drives about 9 m
    # The pose channel says the same as the transform.
    assert [(p["frame_id"], p["position"]) for p in poses] == [("map", t) for t in translations]


async def test_a_live_feed_moves_the_vehicle_from_its_first_map_origin(kitti_root: Path, kitti_log: Path) -> None:
    updates = kitti_updates(kitti_log)
    origins = [update["poses"]["/vehicle_pose"]["map_origin"] for update in updates]
    metadata, frames = kitti_source(kitti_log)
    async with running_server(kitti_root) as server:
        feed = server.live.feed("car")
        feed.set_metadata(metadata)
        url = f"ws://127.0.0.1:{server.port}/?session_type=live&log=car"
        reading = asyncio.ensure_future(
            foxglove_client(url, "foxglove.websocket.v1", options=("--times", str(len(frames))))
        )
        await foxglove_subscribed(server, every=True)
        for frame in frames:
            await feed.publish(frame)
        out = await reading
    translations = [
        {k: t["translation"].get(k, 0.0) for k in "xyz"} for t in out["topics"]["/vehicle_pose"]["summaries"]
    ]
    assert len(translations) == len(frames)
    for translation, origin in zip(translations, origins):
        assert math.hypot(translation["x"], translation["y"]) == pytest.approx(
            haversine(origins[0], origin), rel=0.01, abs=0.05
        )


async def test_the_first_layout_shows_the_cloud_the_camera_the_car_and_a_plot(kitti_root: Path) -> None:
    async with running_server(kitti_root) as server:
        status, headers, body = await asyncio.to_thread(http_get, server.port, "/api/logs/kitti/layout.json")
        missing, _, _ = await asyncio.to_thread(http_get, server.port, "/api/logs/nothing/layout.json")
        async with connect(f"ws://127.0.0.1:{server.port}/?log=kitti", subprotocols=["foxglove.websocket.v1"]) as ws:  # type: ignore[list-item]
            advertised = {c["topic"]: c for c in (await opened(ws))[1]}
    assert status == 200 and headers["Content-Type"] == "application/json" and missing == 404
    layout = json.loads(body)
    panels = layout["configById"]
    three_d = panels["3D!xviz"]
    assert three_d["followTf"] == "/vehicle_pose"
    shown = {topic for topic, settings in three_d["topics"].items() if settings["visible"]}
    assert {"/lidar/points", "/vehicle_pose/pose", "/vehicle/trajectory"} <= shown <= set(advertised)
    assert advertised[panels["Image!xviz"]["imageMode"]["imageTopic"]]["schemaName"] == "foxglove.CompressedImage"
    plotted = panels["Plot!xviz"]["paths"][0]["value"].removesuffix(".value")
    assert json.loads(advertised[plotted]["schema"])["properties"]["value"]["type"] == "number"

    # The layout tree places each configured panel once.
    def leaves(node: Any) -> list[str]:
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(node["second"])

    assert sorted(leaves(layout["layout"])) == sorted(panels)
