"""What an operator relies on: configuration precedence, logs, TLS, tokens, origins, metrics."""

from __future__ import annotations

import asyncio
import json
import logging
import os
import ssl
import sys
import urllib.error
import urllib.request
from pathlib import Path

import pytest
import trustme
from prometheus_client.parser import text_string_to_metric_families
from websockets.asyncio.client import connect
from websockets.exceptions import InvalidStatus

from helpers import client, metric, run_cli, running_server, ten_hz, write_log
from xviz_server.codec import decode


@pytest.fixture
def root(tmp_path: Path) -> Path:
    write_log(tmp_path / "logs" / "drive", ten_hz(5))
    return tmp_path / "logs"


def effective(output: str) -> dict[str, str]:
    return dict(line.split(" = ", 1) for line in output.splitlines() if " = " in line)


def test_configuration_precedence_flag_env_file_default(tmp_path: Path):
    config = tmp_path / "server.toml"
    config.write_text('port = 4000\ncache_mb = 64\nhost = "0.0.0.0"\nallowed_origins = ["https://a.example"]\n')
    result = run_cli("config", "--config", str(config), "--host", "10.0.0.1", XVIZ_PORT="5000")
    assert result.returncode == 0, result.stderr
    values = effective(result.stdout)
    assert values["host"] == '"10.0.0.1"'  # flag
    assert values["port"] == "5000"  # environment over file
    assert values["cache_mb"] == "64.0"  # file over default
    assert values["max_sessions"] == "256"  # default
    assert values["allowed_origins"] == '["https://a.example"]'
    by_env = run_cli("config", XVIZ_CONFIG=str(config))
    assert effective(by_env.stdout)["port"] == "4000"


@pytest.mark.parametrize(
    "content, message",
    [
        ("cache_megabytes = 64\n", "--cache-megabytes: Extra inputs are not permitted"),
        ("port = 99999\n", "--port: Input should be less than or equal to 65535"),
    ],
)
def test_bad_configuration_is_a_clear_cli_error(tmp_path: Path, content: str, message: str):
    config = tmp_path / "bad.toml"
    config.write_text(content)
    result = run_cli("serve", "--config", str(config))
    assert result.returncode == 2 and message in result.stderr
    missing = run_cli("serve", "--config", str(tmp_path / "nope.toml"))
    assert missing.returncode == 2 and "nope.toml not found" in missing.stderr


async def test_json_log_lines_for_sessions_and_errors(root: Path):
    env = {k: v for k, v in os.environ.items() if not k.startswith("XVIZ_")}
    process = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "xviz_server",
        "serve",
        "--data-dir",
        str(root),
        "--port",
        "0",
        "--log-format",
        "json",
        stderr=asyncio.subprocess.PIPE,
        env=env,
    )
    lines = []
    while True:
        line = (await asyncio.wait_for(process.stderr.readline(), 30)).decode()
        lines.append(json.loads(line))
        if "listening on" in lines[-1]["message"]:
            port = int(lines[-1]["message"].rsplit(":", 1)[1].strip("/"))
            break
    async with connect(f"ws://127.0.0.1:{port}/drive") as websocket:
        await websocket.recv()
        await websocket.send("{broken")
        await websocket.recv()
    rest: list[str] = []
    while not any("session end" in line for line in rest):  # logged as the session ends, before the server stops
        rest.append((await asyncio.wait_for(process.stderr.readline(), 30)).decode())
        assert rest[-1], "the server exited"
    process.terminate()
    rest += (await process.stderr.read()).decode().splitlines()
    await process.wait()
    events = {line["event"]: line for line in map(json.loads, rest) if "event" in line}
    assert {"session start", "error sent", "session end"} <= set(events)
    end = events["session end"]
    assert (
        end["log"] == "drive"
        and end["format"] == "BINARY"
        and end["reason"] == "1000"
        and end["remote"].startswith("127.0.0.1:")
    )
    assert {"frames", "bytes", "duration", "time", "level"} <= set(end)
    assert events["error sent"]["kind"] == "malformed" and "invalid JSON" in events["error sent"]["message"]


async def test_tls_serves_wss_and_https(root: Path, tmp_path: Path):
    authority = trustme.CA()
    certificate = authority.issue_cert("127.0.0.1", "localhost")
    certfile, keyfile = tmp_path / "cert.pem", tmp_path / "key.pem"
    certificate.private_key_and_cert_chain_pem.write_to_path(str(certfile))
    certificate.private_key_pem.write_to_path(str(keyfile))
    trusted = ssl.create_default_context()
    authority.configure_trust(trusted)
    async with running_server(root, certfile=certfile, keyfile=keyfile) as server:
        async with connect(f"wss://127.0.0.1:{server.port}/drive", ssl=trusted) as websocket:
            assert decode(await websocket.recv())["type"] == "xviz/metadata"
        body = await asyncio.to_thread(
            lambda: urllib.request.urlopen(f"https://127.0.0.1:{server.port}/healthz", context=trusted).read()
        )
        assert body == b"ok\n"
        with pytest.raises(ssl.SSLError):  # a client that does not trust the certificate
            async with connect(f"wss://127.0.0.1:{server.port}/drive", ssl=ssl.create_default_context()):
                pass


async def test_viewer_token(root: Path):
    async with running_server(root, viewer_token="letmein") as server:
        with pytest.raises(InvalidStatus) as refused:
            async with client(server, "/drive"):
                pass
        assert refused.value.response.status_code == 401
        async with client(server, "/drive?token=letmein") as c:
            assert (await c.recv())["type"] == "xviz/metadata"
        async with client(server, "/drive", additional_headers={"Authorization": "Bearer letmein"}) as c:
            assert (await c.recv())["type"] == "xviz/metadata"

        def status(path: str) -> int:
            try:
                return urllib.request.urlopen(f"http://127.0.0.1:{server.port}{path}").status
            except urllib.error.HTTPError as error:
                return error.code

        assert await asyncio.to_thread(status, "/") == 401
        assert await asyncio.to_thread(status, "/?token=letmein") == 200
        assert await asyncio.to_thread(status, "/healthz") == 200  # health checks need no token
        # A repeated token is none: a proxy in front may read another of its values than the server.
        for twice in ["/?token=letmein&token=wrong", "/?token=wrong&token=letmein", "/?token=letmein&token=letmein"]:
            assert await asyncio.to_thread(status, twice) == 401, twice
        with pytest.raises(InvalidStatus) as refused:
            async with client(server, "/drive?token=letmein&token=other"):
                pass
        assert refused.value.response.status_code == 401
    async with running_server(root, ingest_token="pushme") as server:
        with pytest.raises(InvalidStatus) as refused:
            await connect(f"ws://127.0.0.1:{server.port}/ingest/car?token=pushme&token=pushme")
        assert refused.value.response.status_code == 403


@pytest.mark.parametrize("name", ["viewer_token", "ingest_token", "map_token"])
@pytest.mark.parametrize("value", ["", "  "])
def test_an_empty_token_is_refused_at_start(name: str, value: str):
    result = run_cli("serve", "--port", "0", **{f"XVIZ_{name.upper()}": value})
    assert result.returncode == 2, result.stderr
    assert f"--{name.replace('_', '-')}: Value error, is empty (XVIZ_{name.upper()}= or a blank flag)" in result.stderr


async def test_a_session_end_says_which_side_closed(root: Path, caplog: pytest.LogCaptureFixture):
    """A viewer whose own program fails closes with 1011 (websockets' client does): the client's code, not the
    server's failing; a viewer whose connection drops sent no code at all."""
    caplog.set_level(logging.INFO, logger="xviz_server")
    async with running_server(root) as server:
        async with client(server, "/drive") as c:
            await c.recv()
        with pytest.raises(RuntimeError):
            async with connect(f"ws://127.0.0.1:{server.port}/drive") as websocket:
                await websocket.recv()
                raise RuntimeError("the viewer's own bug")
        websocket = await connect(f"ws://127.0.0.1:{server.port}/drive")
        await websocket.recv()
        websocket.transport.abort()
        for _ in range(100):
            ends = [record.getMessage() for record in caplog.records if record.getMessage().startswith("session end")]
            if len(ends) == 3:
                break
            await asyncio.sleep(0.05)
    assert [end.partition(" reason=")[2] for end in ends] == [
        "1000 closed_by=client",
        "1011 closed_by=client",
        "connection lost",
    ]


async def test_allowed_origins(root: Path):
    async with running_server(root, allowed_origins=["https://viewer.example.com"]) as server:
        async with client(server, "/drive", origin="https://viewer.example.com") as c:
            assert (await c.recv())["type"] == "xviz/metadata"
        async with client(server, "/drive") as c:  # scripts send no Origin
            assert (await c.recv())["type"] == "xviz/metadata"
        with pytest.raises(InvalidStatus) as refused:
            async with client(server, "/drive", origin="https://evil.example.com"):
                pass
        assert refused.value.response.status_code == 403


async def test_metrics_parse_as_prometheus_text(root: Path):
    async with running_server(root) as server:
        async with client(server, "/drive") as c:
            await c.recv()
            await c.send("transform_log", {"id": "m"})
            await c.until("transform_log_done", "m")
            await c.send("transform_point_in_time", {"id": "p", "query_timestamp": 100.2})
            await c.recv()
            await c.websocket.send("{")
            await c.recv()
        text = await asyncio.to_thread(
            lambda: urllib.request.urlopen(f"http://127.0.0.1:{server.port}/metrics").read().decode()
        )
    families = {family.name: family for family in text_string_to_metric_families(text)}
    for name in (
        "xviz_sessions_open",
        "xviz_sessions",
        "xviz_frames_sent",
        "xviz_bytes_sent",
        "xviz_cache_hits",
        "xviz_cache_misses",
        "xviz_cache_bytes",
        "xviz_cache_evictions",
        "xviz_live_dropped_updates",
        "xviz_errors",
        "xviz_request_seconds",
        "xviz_first_frame_seconds",
    ):
        assert name in families, name
    assert metric(text, "xviz_frames_sent_total", format="BINARY") == 6  # 5 frames and the complete state
    assert metric(text, "xviz_errors_total", kind="malformed") == 1
    assert metric(text, "xviz_request_seconds_count", type="transform_point_in_time") == 1
    assert families["xviz_request_seconds"].type == "histogram"
