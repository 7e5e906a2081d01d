"""The built-in viewer: HTTP serving of the page and, in headless Chromium, the page itself.

The HTTP tests serve a small bundle written here; the browser tests need the real
bundle (``scripts/build-viewer.sh``), playwright-core (``viewer/node_modules``) and
Debian's chromium, all of which ``scripts/test.sh`` installs. Each browser test
keeps its screenshot in ``tests/artifacts/`` (git-ignored).
"""

from __future__ import annotations

import asyncio
import gzip
import json
import os
import re
import shutil
import subprocess
import sys
import urllib.parse
import urllib.request
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from devkit.fleet import write_fleet
from devkit.tclink import can_shape_links, tc_link
from devkit.tcpproxy import shaped_link
from helpers import foxglove_client, http_get, metadata, metric, running_server, ten_hz, write_demo, write_log
from xviz_server.catalog import parse_query
from xviz_server.codec import Format
from xviz_server.server import XVIZServer
from xviz_server.settings import Settings
from xviz_server.viewer import SETTINGS_SLOT, STATIC_DIR, STYLE_HASHES, ViewerPage, accepted_encodings

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[1]
DRIVER = REPO / "tests" / "browser.mjs"
ARTIFACTS = REPO / "tests" / "artifacts"
CHROMIUM = Path("/usr/bin/chromium")
BROWSER_TIMEOUT_MS = 90_000
ASSET = "viewer-ABC123.js"
SCRIPT = b"console.log('the viewer');\n" * 50


def get(server: XVIZServer, path: str, method: str = "GET", **headers: str) -> tuple[int, dict[str, str], bytes]:
    """A plain HTTP GET (or ``method``) to the server: status, headers, body (as sent, not decoded)."""
    return http_get(server.port, path, method, **headers)


@pytest.fixture
def bundle(tmp_path: Path) -> Path:
    """A bundle in the layout build.mjs writes: index.html, a hashed asset and its compressed copies."""
    directory = tmp_path / "bundle"
    directory.mkdir()
    (directory / "index.html").write_text(f'<!doctype html>{SETTINGS_SLOT.decode()}<script src="{ASSET}"></script>')
    (directory / ASSET).write_bytes(SCRIPT)
    (directory / f"{ASSET}.gz").write_bytes(gzip.compress(SCRIPT))
    (directory / f"{ASSET}.br").write_bytes(b"brotli bytes as build.mjs wrote them")
    return directory


async def test_a_browser_gets_the_page_and_other_clients_the_catalog(tmp_path: Path, bundle: Path):
    async with running_server(tmp_path) as server:
        server.viewer = ViewerPage(bundle, server.workers)
        status, headers, body = await asyncio.to_thread(
            get, server, "/", Accept="text/html,application/xhtml+xml,*/*;q=0.8"
        )
        assert status == 200 and body == (bundle / "index.html").read_bytes().replace(
            SETTINGS_SLOT, SETTINGS_ELEMENT % b"{}"
        )
        assert headers["Content-Type"] == "text/html; charset=utf-8"
        assert headers["Cache-Control"] == "no-cache" and headers["Vary"] == "Accept"
        for path, accept in [("/", "application/json"), ("/", "*/*"), ("/api/logs", "text/html"), ("/logs", "")]:
            status, headers, body = await asyncio.to_thread(get, server, path, Accept=accept)
            assert status == 200 and headers["Content-Type"] == "application/json", (path, accept)
            assert set(json.loads(body)) == {"server", "logs", "live", "next", "indexed", "found"}


def policy(headers: dict[str, str]) -> dict[str, list[str]]:
    """A Content-Security-Policy header's directives and their sources."""
    return {
        name: sources for name, *sources in (part.split() for part in headers["Content-Security-Policy"].split(";"))
    }


async def test_the_page_and_every_answer_carry_the_security_headers(tmp_path: Path, bundle: Path):
    async with running_server(tmp_path) as server:
        server.viewer = ViewerPage(bundle, server.workers)
        _, headers, _ = await asyncio.to_thread(get, server, "/", Accept="text/html")
        directives = policy(headers)
        assert directives["default-src"] == ["'none'"] and directives["script-src"] == ["'self'"]
        assert directives["style-src"] == ["'self'", *STYLE_HASHES] and directives["frame-ancestors"] == ["'none'"]
        assert "https://api.mapbox.com" in directives["connect-src"] and "'self'" in directives["connect-src"]
        assert not [source for sources in directives.values() for source in sources if "unsafe" in source]
        for path, accept in [
            ("/", "text/html"),
            (f"/{ASSET}", "*/*"),
            ("/api/logs", "*/*"),
            ("/healthz", "*/*"),
            ("/nowhere", "*/*"),
        ]:
            _, headers, _ = await asyncio.to_thread(get, server, path, Accept=accept)
            assert headers["X-Content-Type-Options"] == "nosniff" and headers["Referrer-Policy"] == "strict-origin", (
                path
            )
        # HEAD of the page: its headers, no body.
        status, headers, body = await asyncio.to_thread(get, server, "/", method="HEAD", Accept="text/html")
        assert status == 200 and body == b"" and policy(headers) == directives and int(headers["Content-Length"]) > 0
    async with running_server(tmp_path, frame_ancestors=["https://ops.example", "'self'"]) as server:
        _, headers, _ = await asyncio.to_thread(get, server, "/", Accept="text/html")
        if (STATIC_DIR / "index.html").is_file():
            assert policy(headers)["frame-ancestors"] == ["https://ops.example", "'self'"]


@pytest.mark.parametrize(
    "origin", ["https://ops.example; script-src *", "https://a.example https://b.example", "*", "javascript:"]
)
def test_frame_ancestors_take_origins_only(origin: str):
    from pydantic import ValidationError

    from xviz_server.settings import Settings

    with pytest.raises(ValidationError, match="is not 'self' or an origin"):
        Settings(frame_ancestors=[origin])


SETTINGS_ELEMENT = b'<script id="xviz-settings" type="application/json">%s</script>'


async def test_the_page_is_given_the_map_token_when_it_may_have_it(tmp_path: Path, bundle: Path):
    token = "pk.</script><b>&"
    async with running_server(tmp_path, map_token=token) as server:
        server.viewer = ViewerPage(bundle, server.workers, server.settings.map_token)
        _, _, body = await asyncio.to_thread(get, server, "/", Accept="text/html")
    (settings,) = re.findall(rb'<script id="xviz-settings" type="application/json">(.*?)</script>', body)
    assert json.loads(settings) == {"mapToken": token} and b"</script><b>" not in body
    async with running_server(tmp_path, map_token=token, viewer_token="s3cret") as server:
        server.viewer = ViewerPage(bundle, server.workers, server.settings.map_token, server.settings.viewer_token)
        pages = [
            await asyncio.to_thread(get, server, path, Accept="text/html")
            for path in ["/", "/?token=wrong", "/?token=s3cret"]
        ]
    assert [page[2].count(b"pk.") for page in pages] == [0, 0, 1]


def test_config_does_not_show_the_map_token():
    environment = {**os.environ, "XVIZ_MAP_TOKEN": "pk.from-the-environment"}
    for arguments, env in [(["--map-token", "pk.from-a-flag"], None), ([], environment)]:
        result = subprocess.run(
            [sys.executable, "-m", "xviz_server", "config", *arguments], capture_output=True, text=True, env=env
        )
        assert result.returncode == 0, result.stderr
        assert "# map_token is set (not shown)" in result.stdout and "pk." not in result.stdout


async def test_assets_are_immutable_and_compressed_as_the_client_accepts(tmp_path: Path, bundle: Path):
    async with running_server(tmp_path) as server:
        server.viewer = ViewerPage(bundle, server.workers)
        status, headers, body = await asyncio.to_thread(
            get, server, f"/{ASSET}", **{"Accept-Encoding": "gzip, deflate"}
        )
        assert status == 200 and headers["Content-Encoding"] == "gzip" and gzip.decompress(body) == SCRIPT
        assert headers["Content-Type"] == "text/javascript; charset=utf-8"
        assert headers["Cache-Control"] == "public, max-age=31536000, immutable"
        assert headers["Vary"] == "Accept-Encoding"
        status, headers, body = await asyncio.to_thread(get, server, f"/{ASSET}", **{"Accept-Encoding": "gzip, br"})
        assert headers["Content-Encoding"] == "br" and body == (bundle / f"{ASSET}.br").read_bytes()
        status, headers, body = await asyncio.to_thread(
            get, server, f"/{ASSET}", **{"Accept-Encoding": "br;q=0, identity"}
        )
        assert "Content-Encoding" not in headers and body == SCRIPT
        (bundle / f"{ASSET}.gz").unlink()
        status, headers, body = await asyncio.to_thread(get, server, f"/{ASSET}", **{"Accept-Encoding": "gzip"})
        assert status == 200 and "Content-Encoding" not in headers and body == SCRIPT
        for path in ["/viewer-NOSUCH.js", "/viewer-ABC123.js/../index.html", "/index.html", "/viewer-abc.exe"]:
            status, _, _ = await asyncio.to_thread(get, server, path)
            assert status == 404, path


async def test_without_a_bundle_a_browser_is_told_how_to_build_it(tmp_path: Path):
    async with running_server(tmp_path) as server:
        server.viewer = ViewerPage(tmp_path / "never-built", server.workers)
        status, headers, body = await asyncio.to_thread(get, server, "/", Accept="text/html")
        assert status == 404 and body.count(b"\n") == 1 and b"scripts/build-viewer.sh" in body
        status, headers, body = await asyncio.to_thread(get, server, "/", Accept="application/json")
        assert status == 200 and "logs" in json.loads(body)


def test_accepted_encodings_follow_quality_values():
    from websockets.datastructures import Headers
    from websockets.http11 import Request

    def parse(value: str) -> set[str]:
        return accepted_encodings(Request("/", Headers({"Accept-Encoding": value})))

    assert parse("gzip, deflate, br") == {"gzip", "deflate", "br"}
    assert parse("br;q=0, GZIP;q=0.5") == {"gzip"}
    assert parse("gzip;q=nonsense, br") == {"br"}
    assert parse("") == set()


# --- in the browser ----------------------------------------------------------------------

browser = pytest.mark.skipif(
    not (STATIC_DIR / "index.html").is_file()
    or not (REPO / "viewer" / "node_modules" / "playwright-core").is_dir()
    or not CHROMIUM.is_file()
    or shutil.which("node") is None,
    reason="needs the viewer bundle, playwright-core and chromium: run scripts/test.sh",
)


async def open_page(
    server: XVIZServer,
    path: str,
    screenshot: str,
    port: int | None = None,
    namespace: str | None = None,
    **options: Any,
) -> dict[str, Any]:
    """Open ``path`` of the server in headless Chromium with tests/browser.mjs; its report.

    ``port``: of what listens there instead (a proxy on 127.0.0.1); ``namespace``: run the browser in
    that network namespace, which reaches the server at its own host address.
    """
    ARTIFACTS.mkdir(exist_ok=True)
    shot = ARTIFACTS / f"viewer-{screenshot}.png"
    host = server.settings.host if namespace else "127.0.0.1"
    arguments = {
        "url": f"http://{host}:{port or server.port}{path}",
        "screenshot": str(shot),
        "timeout": BROWSER_TIMEOUT_MS,
        "hosts": [host],
    }
    prefix = ["ip", "netns", "exec", namespace] if namespace else []
    process = await asyncio.create_subprocess_exec(
        *prefix,
        "node",
        str(DRIVER),
        json.dumps({**arguments, **options}),
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
    )
    stdout, stderr = await process.communicate()
    assert process.returncode == 0, stderr.decode()
    report: dict[str, Any] = json.loads(stdout)
    report["screenshot"] = shot
    print(f"screenshot: {shot}; first drawn frame after {report['firstDrawnMs']} ms")
    return report


def assert_drawn_cleanly(report: dict[str, Any]) -> None:
    """Frames came, the 3D view shows a picture, and nothing went wrong on the page (nor did its
    Content-Security-Policy refuse anything); the page's WebSocket URL carries only what it means to."""
    assert report["pageErrors"] == [] and report["consoleErrors"] == [] and report["alerts"] == []
    assert report["failedRequests"] == [] and report["externalRequests"] == []
    assert report["cspViolations"] == []
    assert report["socketUrls"] and not any("[object" in url or "bufferAfter" in url for url in report["socketUrls"]), (
        report["socketUrls"]
    )
    assert report["frames"] >= 3 and report["drawn"]
    box = report["canvasBox"]
    image = np.asarray(Image.open(report["screenshot"]).convert("L"), dtype=np.float32)
    canvas = image[int(box["y"]) : int(box["y"] + box["height"]), int(box["x"]) : int(box["x"] + box["width"])]
    assert canvas.size > 0 and canvas.std() > 10, "the 3D view is blank"


def assert_stream_list_shows(report: dict[str, Any], streams: list[str]) -> None:
    """StreamSettingsPanel groups streams by their first segment: ``/a/b/c`` shows as ``/a`` over ``/b/c``."""
    shown = set(report["streamsText"].split("\n"))
    for stream in streams:
        group, _, rest = stream.strip("/").partition("/")
        assert f"/{group}" in shown and (not rest or f"/{rest}" in shown), stream


async def listed(server: XVIZServer) -> list[dict[str, Any]]:
    """The first page of the server's catalog, as ``GET /api/logs`` lists it."""
    return (await server.indexer.page(parse_query({})))["logs"]


def counted(server: XVIZServer, name: str, **labels: str) -> int:
    """The value of one sample of the server's metrics (0 when it has none yet)."""
    _, _, body = get(server, "/metrics")
    return int(metric(body, name, **labels))


def point_in_time_requests(server: XVIZServer) -> int:
    """How many ``xviz/transform_point_in_time`` requests the server answered."""
    return counted(server, "xviz_request_seconds_count", type="transform_point_in_time")


@browser
async def test_the_kitti_log_opens_directly(tmp_path: Path, kitti_log: Path):
    (tmp_path / kitti_log.name).symlink_to(kitti_log)
    async with running_server(tmp_path) as server:
        # Metadata, the first frame, and the 25 frames asked for once it was drawn.
        report = await open_page(server, f"/?log={kitti_log.name}", "kitti", frames=27)
        streams = (await server.shelf.open(kitti_log.name)).streams
        queries = await asyncio.to_thread(point_in_time_requests, server)
    assert_drawn_cleanly(report)
    assert_stream_list_shows(report, streams)
    # The first frame is asked for on its own (point in time), then the buffer: the 25 frames.
    # (A seek before the buffer reaches the current time may ask once more: one at a time.)
    assert queries in (1, 2) and report["frames"] >= 1 + queries + 25
    marks = report["marks"]
    assert (
        marks["bundle"] <= marks["script"] <= marks["catalog"]
        and marks["metadata"] <= marks["first-frame"] <= report["firstDrawnMs"]
    )
    # The GPU drew the first frame (a fence after it signalled) before the panels came.
    assert marks["first-frame"] <= marks["first-draw"]


#: The window sizes every panel must fit: a laptop's and a desktop's.
WINDOWS = [{"width": 1280, "height": 800}, {"width": 1920, "height": 1080}]
#: A tick label of the timeline: seconds from the log's start, or minutes and seconds.
TICK = re.compile(r"^(\d+(\.\d+)?\u00a0s|\d+:\d\d(:\d\d)?)$")


def assert_on_screen(report: dict[str, Any], panels: list[str]) -> None:
    """The header, the 3D view, the playback control and every panel and the stream list have a
    box of their own inside the window, with content in it; a table shows rows."""
    layout = report["layout"]
    window = layout["window"]

    def inside(box: dict[str, float] | None, what: str) -> None:
        assert box is not None and box["width"] > 0 and box["height"] > 0, (what, box)
        assert box["x"] >= 0 and box["y"] >= 0, (what, box)
        assert (
            box["x"] + box["width"] <= window["width"] + 0.5 and box["y"] + box["height"] <= window["height"] + 0.5
        ), (what, box, window)

    for part in ("header", "canvas", "playback"):
        inside(layout[part], part)
    assert [section["name"] for section in layout["sections"]] == [*panels, "Streams"]
    for section in layout["sections"]:
        inside(section["box"], section["name"])
        content = section["content"]
        assert content is not None and content["width"] > 0 and content["height"] > 0, section


def assert_ticks_readable(report: dict[str, Any]) -> list[str]:
    """The timeline's labels: several, each a time, no two alike; returned in order."""
    ticks = [text for text in report["layout"]["ticks"] if TICK.match(text)]
    assert len(ticks) >= 4 and len(set(ticks)) == len(ticks), ticks
    return ticks


@browser
@pytest.mark.parametrize("window", WINDOWS, ids=lambda window: f"{window['width']}x{window['height']}")
async def test_every_panel_is_on_screen_with_content(tmp_path: Path, window: dict[str, int]):
    # The demo declares plots and a table ("Road users"): each has a box inside the window, the table shows rows.
    write_demo(tmp_path / "demo", duration=20.0)
    async with running_server(tmp_path) as server:
        report = await open_page(server, "/?log=demo", f"panels-{window['width']}", viewport=window, settle=3000)
        summary = await server.indexer.one("demo")
        assert report["exportLink"] is not None
        status, headers, body = await asyncio.to_thread(get, server, report["exportLink"])
    assert_drawn_cleanly(report)
    assert_on_screen(report, ["Metrics", "Road users"])
    (table,) = [section for section in report["layout"]["sections"] if section["name"] == "Road users"]
    assert table["rows"] >= 3
    assert assert_ticks_readable(report)[0] == "0\u00a0s"
    # The export: an MCAP file of the log from the time shown to its end.
    query = urllib.parse.parse_qs(urllib.parse.urlsplit(report["exportLink"]).query)
    assert urllib.parse.urlsplit(report["exportLink"]).path == "/api/logs/demo/export"
    assert (
        summary["start_time"]
        <= float(query["start"][0])
        < float(query["end"][0])
        == pytest.approx(summary["end_time"], abs=1e-3)
    )
    assert status == 200 and body[:8] == b"\x89MCAP0\r\n"


@browser
@pytest.mark.parametrize("window", WINDOWS, ids=lambda window: f"{window['width']}x{window['height']}")
async def test_every_panel_of_the_kitti_log_is_on_screen(tmp_path: Path, kitti_log: Path, window: dict[str, int]):
    (tmp_path / kitti_log.name).symlink_to(kitti_log)
    async with running_server(tmp_path) as server:
        report = await open_page(
            server, f"/?log={kitti_log.name}", f"kitti-{window['width']}", viewport=window, frames=27, settle=3000
        )
    assert_drawn_cleanly(report)
    assert_on_screen(report, ["Metrics", "Camera"])
    assert_ticks_readable(report)


@browser
async def test_the_timeline_of_a_short_log_reads(tmp_path: Path):
    write_demo(tmp_path / "short", duration=2.5)
    async with running_server(tmp_path) as server:
        report = await open_page(server, "/?log=short", "short-timeline", settle=2000)
    assert_drawn_cleanly(report)
    ticks = assert_ticks_readable(report)
    assert ticks[:3] == ["0.0\u00a0s", "0.2\u00a0s", "0.4\u00a0s"], ticks


@browser
async def test_a_broken_log_shows_the_servers_own_words(tmp_path: Path):
    log = write_log(tmp_path / "broken", ten_hz(10))
    (log / "1-frame.glb").write_bytes(b"glTF" + bytes(40))  # the metadata: a GLB header and nothing else
    write_demo(tmp_path / "demo", duration=1.0)
    async with running_server(tmp_path) as server:
        report = await open_page(server, "/?log=broken", "broken", settle=0)
        _, _, body = await asyncio.to_thread(get, server, "/api/logs/broken")
    cause = json.loads(body)["error"]
    assert cause and report["alerts"] == [cause]  # the catalog's words, not "Stream server error"


@browser
async def test_a_seek_beyond_the_buffer_asks_for_that_point_in_time(tmp_path: Path):
    write_demo(tmp_path / "demo", duration=20.0)  # the page asks for 5 s at a time
    async with running_server(tmp_path) as server:
        report = await open_page(server, "/?log=demo", "seek", seek=0.9)
        queries = await asyncio.to_thread(point_in_time_requests, server)
        (summary,) = await listed(server)
    assert_drawn_cleanly(report)
    # One for the first frame, one (or, while the frames around it arrive, a few) for the seek.
    assert queries >= 2
    seek = report["seek"]
    shown = [
        datetime.strptime(re.findall(r"\d\d:\d\d:\d\d\.\d{3}", text)[-1], "%H:%M:%S.%f")
        for text in (seek["shownBefore"], seek["shownAfter"])
    ]
    assert 15 < (shown[1] - shown[0]).total_seconds() < summary["end_time"] - summary["start_time"]
    assert seek["pictureChange"] >= 2


@browser
async def test_a_point_in_time_with_no_state_is_no_error_to_the_person(tmp_path: Path):
    # The log says it starts at 100 s; its first frame is at 101 s: the page's first query
    # (at its start time) has no answer but an xviz/error, and the frames must still come.
    write_log(tmp_path / "late", ten_hz(60, start=101.0), meta=metadata(start_time=100.0, end_time=107.0))
    async with running_server(tmp_path) as server:
        report = await open_page(server, "/?log=late", "late-start", draw=False, settle=3000)
        refused = await asyncio.to_thread(counted, server, "xviz_errors_total", kind="query")
    assert report["alerts"] == [] and report["pageErrors"] == [] and report["consoleErrors"] == []
    assert refused == 1 and report["frames"] >= 1 + 1 + 40  # metadata, the error, then 101 s to 105 s


@browser
async def test_with_a_map_token_the_page_asks_for_the_base_map(tmp_path: Path, kitti_log: Path):
    (tmp_path / kitti_log.name).symlink_to(kitti_log)
    async with running_server(tmp_path, map_token="pk.test-token") as server:
        report = await open_page(server, f"/?log={kitti_log.name}", "map", settle=3000)
    # The tests use no network: browser.mjs refuses requests beyond loopback, and says which were made.
    assert report["externalRequests"] and all("api.mapbox.com" in url for url in report["externalRequests"])
    assert any("access_token=pk.test-token" in url for url in report["externalRequests"])
    assert report["pageErrors"] == [] and report["drawn"]
    assert report["cspViolations"] == []  # the map's origins are the policy's
    # With a viewer token, a reloaded page (its address holds the token no more) still draws the base map.
    async with running_server(tmp_path, map_token="pk.test-token", viewer_token="s3cret") as server:
        reloaded = await open_page(
            server, f"/?log={kitti_log.name}&token=s3cret", "map-reloaded", reload=True, settle=3000
        )
    assert reloaded["drawn"] and reloaded["pageErrors"] == [] and reloaded["cspViolations"] == []
    assert any("access_token=pk.test-token" in url for url in reloaded["externalRequests"])


@browser
async def test_json_logs_and_converted_datasets_open(tmp_path: Path, shared_dir: Path):
    write_demo(tmp_path / "demo-json", duration=2.0, fmt=Format.JSON)
    drive = shared_dir / "data" / "kitti-raw-2011_09_26_drive_0001-head" / "2011_09_26" / "2011_09_26_drive_0001_sync"
    async with running_server(tmp_path, dataset=[f"kitti:{drive}"]) as server:
        names = {summary["name"]: summary for summary in await listed(server)}
        (dataset,) = set(names) - {"demo-json"}
        assert names["demo-json"]["format"] == "JSON"
        reports = {name: await open_page(server, f"/?log={name}", name.replace("/", "_")) for name in names}
    for name, report in reports.items():
        assert_drawn_cleanly(report)
        assert_stream_list_shows(report, names[name]["streams"])


@browser
async def test_a_click_in_the_catalog_opens_the_log(tmp_path: Path):
    write_demo(tmp_path / "demo", duration=3.0)
    async with running_server(tmp_path) as server:
        report = await open_page(server, "/", "catalog-click", click="demo")
        (summary,) = await listed(server)
    rows = [line.split("\t") for line in report["catalogText"].split("\n")]
    assert rows[0] == ["name", "format", "frames", "duration", "streams", "Foxglove / Lichtblick"]
    assert rows[1][:5] == [
        "demo",
        summary["format"],
        str(summary["frames"]),
        f"{summary['end_time'] - summary['start_time']:.1f} s",
        str(len(summary["streams"])),
    ]
    assert report["url"].endswith("/?log=demo")
    assert_drawn_cleanly(report)
    assert_stream_list_shows(report, summary["streams"])


@browser
async def test_the_catalog_gives_each_log_the_url_that_opens_it_in_foxglove(tmp_path: Path, kitti_log: Path):
    (tmp_path / "drives").mkdir()
    (tmp_path / "drives" / "kitti").symlink_to(kitti_log)
    write_demo(tmp_path / "demo", duration=1.0)
    for settings, path in (({}, "/"), ({"viewer_token": "s3cret"}, "/?token=s3cret")):
        async with running_server(tmp_path, **settings) as server:
            report = await open_page(server, path, "foxglove-url", draw=False, settle=0, foxglove="drives/kitti")
            url = report["foxgloveCopied"]
            # What the page shows and copies, pasted into the published Foxglove client, opens that log.
            out = await foxglove_client(url, "foxglove.websocket.v1")
            token = "&token=s3cret" if settings else ""
            assert url == report["foxgloveUrl"] == f"ws://127.0.0.1:{server.port}/?log=drives/kitti{token}"
            # The same log as a file to seek in: its URL (which serves it), and the app opening it as a remote file.
            file = report["foxgloveFileLink"]
            assert file == f"http://127.0.0.1:{server.port}/api/logs/drives%2Fkitti/file.mcap" + (
                "?token=s3cret" if settings else ""
            )
            target = urllib.parse.urlsplit(file)
            status, headers, _ = await asyncio.to_thread(http_get, server.port, f"{target.path}?{target.query}", "HEAD")
            assert (status, headers["Accept-Ranges"]) == (200, "bytes")
        assert report[
            "foxgloveAppLink"
        ] == "https://app.foxglove.dev/?ds=foxglove-websocket&ds.url=" + urllib.parse.quote(url, safe="")
        assert report["foxgloveFileAppLink"] == "https://app.foxglove.dev/?ds=remote-file&ds.url=" + urllib.parse.quote(
            file, safe=""
        )
        assert report["pageErrors"] == [] and report["failedRequests"] == [] and report["externalRequests"] == []
        assert out["errors"] == [] and out["statuses"] == [] and out["serverInfo"]["metadata"]["log"] == "drives/kitti"
        assert out["topics"]["/lidar/points"]["count"] == 25


@browser
async def test_the_catalog_searches_and_pages(tmp_path: Path):
    fleet = sorted(log.name for log in write_fleet(tmp_path, 230))
    write_demo(tmp_path / "demo", duration=1.0)
    async with running_server(tmp_path) as server:
        paged = await open_page(server, "/", "catalog-pages", draw=False, settle=0, more=2)
        searched = await open_page(server, "/", "catalog-search", draw=False, settle=0, search="SEG-00012")
    assert paged["catalogRows"] == sorted([*fleet, "demo"]) and not paged["moreOffered"]
    assert paged["catalogCount"] == "231 logs" and paged["pageErrors"] == [] and paged["failedRequests"] == []
    assert (
        searched["catalogRows"] == [name for name in fleet if "seg-00012" in name]
        and len(searched["catalogRows"]) == 10
    )
    assert searched["catalogCount"] == "10 of 231 logs match"  # the count follows the search


@browser
async def test_a_deep_link_opens_the_log_at_its_time_and_the_page_links_the_time_shown(tmp_path: Path):
    write_demo(tmp_path / "demo", duration=20.0)
    async with running_server(tmp_path) as server:
        report = await open_page(server, "/?log=demo&t=12", "deep-link", settle=2000)
        start = (await server.indexer.one("demo"))["start_time"]
    assert_drawn_cleanly(report)
    assert report["timeLink"] == "?log=demo&t=12.0"
    # The playback control shows the time of day: 12 s after the log's start (to the frame shown).
    shown = datetime.strptime(re.findall(r"\d\d:\d\d:\d\d\.\d{3}", report["playbackText"])[-1], "%H:%M:%S.%f")
    wanted = datetime.strptime(datetime.utcfromtimestamp(start + 12).strftime("%H:%M:%S.%f"), "%H:%M:%S.%f")
    assert abs((shown - wanted).total_seconds()) < 1, (shown, wanted)


@browser
async def test_a_live_feed_plays(tmp_path: Path):
    source = write_demo(tmp_path / "car", duration=2.0)
    (tmp_path / "empty").mkdir()
    async with running_server(tmp_path / "empty", live_from=source, loop=True, rate=1.0) as server:
        report = await open_page(server, "/?log=car", "live", frames=10)
    assert_drawn_cleanly(report)
    assert report["frames"] >= 10


@browser
async def test_the_page_passes_the_viewer_token_on(tmp_path: Path):
    write_demo(tmp_path / "demo", duration=1.0)
    async with running_server(tmp_path, viewer_token="s3cret") as server:
        allowed = await open_page(server, "/?log=demo&token=s3cret", "token")
        reloaded = await open_page(server, "/?log=demo&token=s3cret", "token-reloaded", reload=True)
        refused = await open_page(server, "/?log=demo", "no-token", settle=0)
    assert_drawn_cleanly(allowed)
    # The token is out of the address bar (and the history) once the page has it; a reload finds it in the tab.
    assert allowed["url"].endswith("/?log=demo") and "s3cret" not in allowed["url"]
    assert_drawn_cleanly(reloaded)
    assert reloaded["url"].endswith("/?log=demo")
    assert refused["frames"] == 0 and len(refused["alerts"]) == 1
    assert "401" in refused["alerts"][0] and "viewer token" in refused["alerts"][0]


@browser
async def test_allowed_origins_apply_to_the_page(tmp_path: Path):
    write_demo(tmp_path / "demo", duration=1.0)
    async with running_server(tmp_path, allowed_origins=["https://elsewhere.example"]) as server:
        report = await open_page(server, "/?log=demo", "other-origin", settle=0)
    assert report["frames"] == 0 and report["pageErrors"] == []
    assert len(report["alerts"]) == 1 and "--allowed-origins" in report["alerts"][0]


@browser
async def test_an_unknown_log_is_shown_to_the_person(tmp_path: Path):
    write_demo(tmp_path / "demo", duration=1.0)
    async with running_server(tmp_path) as server:
        report = await open_page(server, "/?log=nowhere", "unknown", settle=0)
    assert report["alerts"] == ['This server has no log or live feed named "nowhere".']
    assert report["pageErrors"] == []


@browser
async def test_the_page_shows_the_level_of_detail_and_lets_the_person_pick_one(tmp_path: Path, kitti_log: Path):
    (tmp_path / kitti_log.name).symlink_to(kitti_log)
    async with running_server(tmp_path) as server:
        report = await open_page(server, f"/?log={kitti_log.name}", "detail", frames=27, detail="low")
        text = await asyncio.to_thread(lambda: get(server, "/metrics")[2])
    assert_drawn_cleanly(report)
    # Before: the level chosen for what the page reads (a page that parses slower than real time is sent less).
    assert report["detailBefore"].split()[0] in ("full", "high", "medium") and report["detailAfter"].startswith("low")
    assert b'xviz_sessions_by_detail{level="low"} 0.0' in text  # the session ended at low
    assert b'xviz_sessions_by_detail{level="full"} 0.0' in text


@browser
async def test_the_log_plays_behind_a_20_mbps_link(tmp_path: Path, kitti_log: Path):
    # The page, its bundle and the frames come through a TCP proxy that carries 20 Mbit/s.
    (tmp_path / kitti_log.name).symlink_to(kitti_log)
    async with running_server(tmp_path) as server, shaped_link(server.port, 20) as link:
        report = await open_page(server, f"/?log={kitti_log.name}", "20mbps", port=link.port, frames=5, settle=2000)
    assert_drawn_cleanly(report)


@browser
@pytest.mark.skipif(not can_shape_links(), reason="shaping a link with tc needs root, ip and tc")
async def test_the_drive_plays_behind_a_20_mbps_link_at_the_level_it_carries(tmp_path: Path, kitti_log: Path):
    # The browser in a network namespace of its own, the link to it shaped with tc: thinned points, JPEG images.
    (tmp_path / kitti_log.name).symlink_to(kitti_log)
    with tc_link(20) as link:
        async with XVIZServer(Settings(host=link.host, port=0, data_dir=tmp_path)) as server:
            report = await open_page(
                server, f"/?log={kitti_log.name}", "tc-20mbps", namespace=link.namespace, frames=27, detail="low"
            )
            text = await asyncio.to_thread(
                lambda: urllib.request.urlopen(f"http://{link.host}:{server.port}/metrics").read()
            )
    assert_drawn_cleanly(report)
    assert report["detailBefore"].split()[0] in ("medium", "low", "minimal"), report[
        "detailBefore"
    ]  # chosen for the link
    assert report["detailAfter"].startswith("low (link ")
    assert b'xviz_sessions_by_detail{level="full"} 0.0' in text
