"""The real Lichtblick web app in Chromium, connected to this server as a user connects: every channel listed, a Plot
drawn, each message at its log's time, the vehicle moving, and the first layout the server offers.

Lichtblick is not in this repository: build its web app from its public source as its Dockerfile does
(``yarn install`` and ``yarn run web:build:prod``; the static files land in ``web/.webpack``) and point
``XVIZ_LICHTBLICK_DIR`` at that folder. Without it these tests are skipped. The app is served here on loopback
with a layout put in its ``index.html`` where its Docker image puts ``/lichtblick/default-layout.json``: the one
``GET /api/logs/NAME/layout.json`` answers, and panels of the test's own that read what the app shows.
"""

from __future__ import annotations

import asyncio
import functools
import json
import os
import re
import threading
from collections.abc import Iterator
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any
from urllib.parse import quote

import pytest
from websockets.asyncio.client import connect

from devkit.rosbag_kitti import RAW, write_bag
from xviz_server.datasets.kitti import KittiDrive

from helpers import http_get, running_server

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[1]
DRIVER = REPO / "tests" / "lichtblick.mjs"
ARTIFACTS = REPO / "tests" / "artifacts"
APP = os.environ.get("XVIZ_LICHTBLICK_DIR")
PLACEHOLDER = "/*LICHTBLICK_SUITE_DEFAULT_LAYOUT_PLACEHOLDER*/"
#: The colour of the test's Plot series, counted in the Plot panel's pixels.
PLOT_COLOUR = "#ff00ff"

if not APP or not (Path(APP) / "index.html").is_file():
    pytest.skip("set XVIZ_LICHTBLICK_DIR to a Lichtblick web build (its Dockerfile's yarn run web:build:prod: web/.webpack)",
                allow_module_level=True)

#: A user script (Lichtblick's "User Scripts") that republishes each message's receive time, which the app took
#: from the server's time messages, beside the time the message itself carries.
STAMPS_SCRIPT = """
import { Input } from "./types";
export const inputs = ["%s"];
export const output = "/studio_script/stamps";
type Out = { receive: string; stamp: string };
export default function script(event: Input<"%s">): Out {
  const receive = event.receiveTime.sec + event.receiveTime.nsec / 1e9;
  return { receive: "R" + receive.toFixed(3), stamp: "S" + (event.message as any).timestamp.toFixed(3) };
}
"""


class _AppHandler(SimpleHTTPRequestHandler):
    """Lichtblick's static files, with ``index.html`` carrying the layout (as its Docker image's entrypoint does)."""

    layout = b"{}"

    def do_GET(self) -> None:  # noqa: N802 (the standard library's name)
        if self.path.split("?")[0] in ("/", "/index.html"):
            page = (Path(self.directory) / "index.html").read_bytes().replace(PLACEHOLDER.encode(), self.layout)
            self.send_response(200)
            self.send_header("Content-Type", "text/html")
            self.send_header("Content-Length", str(len(page)))
            self.end_headers()
            self.wfile.write(page)
            return
        super().do_GET()

    def log_message(self, format: str, *args: Any) -> None:
        pass


@pytest.fixture
def app() -> Iterator[Any]:
    """Serve the app on loopback; call the result with a layout to get the app's address."""
    handler = type("Handler", (_AppHandler,), {})
    server = ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(handler, directory=APP))
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()

    def serve(layout: dict[str, Any]) -> str:
        handler.layout = json.dumps(layout).encode()
        return f"http://127.0.0.1:{server.server_address[1]}/"

    yield serve
    server.shutdown()
    thread.join()


async def advertised(port: int, log: str) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The server's ``serverInfo`` and the channels it advertises for ``log``."""
    async with connect(f"ws://127.0.0.1:{port}/?log={log}", subprotocols=["foxglove.websocket.v1"]) as ws:  # type: ignore[list-item]
        info = json.loads(await asyncio.wait_for(ws.recv(), 30))
        channels: list[dict[str, Any]] = json.loads(await asyncio.wait_for(ws.recv(), 30))["channels"]
    return info, channels


def with_probes(served: dict[str, Any], velocity: str, pose: str) -> dict[str, Any]:
    """The server's layout with the test's own panels beside it: a Plot of the ``velocity`` series in one colour, the
    vehicle's transform (topic ``pose``) as Raw Messages, and a user script's receive and message times of
    ``velocity`` as Raw Messages."""
    layout = json.loads(json.dumps(served))
    config = layout["configById"]
    config["Plot!xviz"] = {
        "paths": [{"value": f"{velocity}.value", "enabled": True, "timestampMethod": "receiveTime", "color": PLOT_COLOUR}],
        "showLegend": False, "legendDisplay": "none", "showXAxisLabels": True, "showYAxisLabels": True, "isSynced": True,
        "xAxisVal": "timestamp",
    }
    raw = {"diffEnabled": False, "diffMethod": "custom", "diffTopicPath": "", "showFullMessageForDiff": False, "expansion": "all"}
    config["RawMessages!pose"] = {**raw, "topicPath": f"{pose}.translation"}
    config["RawMessages!stamps"] = {**raw, "topicPath": "/studio_script/stamps"}
    layout["userNodes"] = {"stamps": {"name": "stamps", "sourceCode": STAMPS_SCRIPT % (velocity, velocity)}}
    layout["layout"] = {
        "first": "3D!xviz",
        "second": {
            "first": {"first": "Image!xviz", "second": "Plot!xviz", "direction": "column"},
            "second": {"first": "RawMessages!pose", "second": "RawMessages!stamps", "direction": "column"},
            "direction": "column",
        },
        "direction": "row", "splitPercentage": 50,
    }
    return layout


async def drive(url: str, shot: Path, **options: Any) -> dict[str, Any]:
    arguments = {"url": url, "screenshot": str(shot), "plotColor": PLOT_COLOUR, "timeout": 90_000, **options}
    process = await asyncio.create_subprocess_exec(
        "node", str(DRIVER), json.dumps(arguments), stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
    )
    stdout, stderr = await process.communicate()
    assert process.returncode == 0, stderr.decode()
    report: dict[str, Any] = json.loads(stdout)
    print(json.dumps({k: v for k, v in report.items() if k != "consoleWarnings"}, indent=1)[:4000])
    return report


def numbers(text: str, key: str) -> list[float]:
    return [float(value) for value in re.findall(rf"{key}\s*:?\s*\"?(-?[0-9.]+(?:e-?\d+)?)", text)]


async def check_log(app: Any, server: Any, log: str, velocity: str, pose: str, shot: str, frames: int) -> dict[str, Any]:
    """Open ``log`` in the app as a user does (a Foxglove WebSocket connection by URL) and check what it shows."""
    status, _, body = await asyncio.to_thread(http_get, server.port, f"/api/logs/{quote(log)}/layout.json")
    assert status == 200
    info, channels = await advertised(server.port, log)
    socket = f"ws://127.0.0.1:{server.port}/?log={log}"
    url = app(with_probes(json.loads(body), velocity, pose)) + f"?ds=foxglove-websocket&ds.url={quote(socket, safe='')}"
    ARTIFACTS.mkdir(exist_ok=True)
    # Played to the end once the last frame's message shows (else the driver stops at its timeout).
    last = f"S{info['dataEndTime']['sec'] + info['dataEndTime']['nsec'] / 1e9:.3f}"
    report = await drive(url, ARTIFACTS / shot, panels=["RawMessages!pose", "RawMessages!stamps", "Plot!xviz"],
                         until={"RawMessages!stamps": last})
    assert report["externalRequests"] == [] and report["pageErrors"] == []
    # Every advertised channel is listed, under its schema; no problem with a schema.
    listed = {row[0]: row[1] if len(row) > 1 else None for row in report["topics"]}
    assert {c["topic"]: c["schemaName"] for c in channels} == {t: s for t, s in listed.items() if not t.startswith("/studio_script")}
    assert not [p for p in report["problems"] if "schema" in p.lower() or "unsupported" in p.lower()], report["problems"]
    # A Plot of the velocity draws its line.
    assert report["plots"].get("Plot!xviz", 0) > 100
    # Each velocity message as the app shows it: received at the time the message carries (its XVIZ timestamp).
    pairs = [(numbers(text, "R"), numbers(text, "S")) for text in report["raw"].get("RawMessages!stamps", [])]
    pairs = [(r[0], s[0]) for r, s in pairs if r and s]
    assert len(pairs) >= frames // 2, report["raw"].get("RawMessages!stamps")
    assert all(receive == stamp for receive, stamp in pairs), pairs
    # The vehicle's transform moves over the drive.
    xs = [numbers(text, "x") for text in report["raw"].get("RawMessages!pose", [])]
    ys = [numbers(text, "y") for text in report["raw"].get("RawMessages!pose", [])]
    places = [(x[0], y[0]) for x, y in zip(xs, ys) if x and y]
    assert len(places) >= 2 and max(abs(x - places[0][0]) + abs(y - places[0][1]) for x, y in places) > 1.0, places
    assert report["drawn3d"]
    return report


async def test_lichtblick_shows_a_kitti_log(app: Any, kitti_root: Path) -> None:
    async with running_server(kitti_root) as server:
        await check_log(app, server, "kitti", "/vehicle/velocity", "/vehicle_pose", "lichtblick-kitti.png", 25)


async def test_lichtblick_shows_a_ros2_mcap(app: Any, shared_dir: Path, tmp_path: Path) -> None:
    bag = write_bag(tmp_path / "drive.mcap", "mcap", drive=KittiDrive(shared_dir / "data" / RAW), frames=25)
    async with running_server(None, dataset=[f"rosbag:{bag}"]) as server:
        await check_log(app, server, "drive", "/xviz/odom/speed", "/xviz/vehicle_pose", "lichtblick-ros2-mcap.png", 25)
