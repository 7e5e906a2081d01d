"""What the tests share: logs written in the reference layout, a running server and a
client, the published client's drivers (node), and message comparisons.

Test modules import from here only, never from one another.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import inspect
import json
import os
import re
import shutil
import struct
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import AsyncIterator, Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from prometheus_client.parser import text_string_to_metric_families
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed
from websockets.frames import Close

from devkit.data import MISSING, present
from xviz_server.codec import Format, decode, encode
from xviz_server.layout import INDEX_FILE, METADATA_NUMBER, file_number, index_document, update_span
from xviz_server.server import XVIZServer
from xviz_server.settings import Settings

INTEROP = Path(__file__).parent / "interop"


def require_data() -> None:
    """Skip the test, with one line saying how to get it, unless the real data is there.

    In CI (``CI`` set), which has the data, its absence is a failure: the tests
    that need it must run there.
    """
    if present():
        return
    if os.environ.get("CI"):
        pytest.fail(MISSING, pytrace=False)
    pytest.skip(MISSING)


#: For a module whose tests read the real data outside the ``shared_dir`` fixture.
needs_data = pytest.mark.usefixtures("shared_dir")
#: A 2 x 1 PNG image.
PNG_2X1 = bytes.fromhex(
    "89504e470d0a1a0a0000000d494844520000000200000001080200000"
    "07b40e8dd0000001049444154789c63f8cfc0c0c0c0c00000001eff01ff"
    "987385d10000000049454e44ae426082"
)

DRIVER = INTEROP / "xviz-session.js"


# ------------------------------------------------------------ comparisons


def assert_same_message(actual: Any, expected: Any, path: str = "$", *, lists_as_arrays: bool = False) -> None:
    """Assert two decoded messages hold the same data.

    numpy arrays compare by dtype, shape and values; ``bytes`` and
    ``memoryview`` compare by content; everything else with ``==``. With
    ``lists_as_arrays``, ``actual`` may hold nested lists where ``expected``
    has arrays (a JSON message against a GLB one): they are read as arrays
    of the expected dtype, so the values must match to the bit.
    """
    if isinstance(expected, np.ndarray):
        if lists_as_arrays and isinstance(actual, list):
            actual = np.asarray(actual, dtype=expected.dtype)
        assert isinstance(actual, np.ndarray), f"{path}: {type(actual).__name__} is not an array"
        assert actual.dtype == expected.dtype, f"{path}: dtype {actual.dtype} != {expected.dtype}"
        assert actual.shape == expected.shape, f"{path}: shape {actual.shape} != {expected.shape}"
        assert np.array_equal(actual, expected), f"{path}: values differ"
    elif isinstance(expected, (bytes, memoryview)):
        assert isinstance(actual, (bytes, memoryview)), f"{path}: {type(actual).__name__} is not binary"
        assert bytes(actual) == bytes(expected), f"{path}: bytes differ"
    elif isinstance(expected, dict):
        assert isinstance(actual, dict), f"{path}: {type(actual).__name__} is not an object"
        assert list(actual) == list(expected), f"{path}: keys {list(actual)} != {list(expected)}"
        for key in expected:
            assert_same_message(actual[key], expected[key], f"{path}[{key!r}]", lists_as_arrays=lists_as_arrays)
    elif isinstance(expected, list):
        assert isinstance(actual, list), f"{path}: {type(actual).__name__} is not a list"
        assert len(actual) == len(expected), f"{path}: length {len(actual)} != {len(expected)}"
        for index, (a, e) in enumerate(zip(actual, expected)):
            assert_same_message(a, e, f"{path}[{index}]", lists_as_arrays=lists_as_arrays)
    else:
        assert actual == expected, f"{path}: {actual!r} != {expected!r}"


def metric(text: str | bytes, name: str, **labels: str) -> float:
    """The sum of the samples named ``name`` on a ``/metrics`` page whose labels include ``labels`` (0 if none).

    The page is parsed as Prometheus text (``prometheus_client``'s parser),
    so a page it cannot read fails the test.
    """
    page = text.decode() if isinstance(text, bytes) else text
    return sum(
        sample.value
        for family in text_string_to_metric_families(page)
        for sample in family.samples
        if sample.name == name and labels.items() <= sample.labels.items()
    )


def assert_same_parse(mine, theirs, path: str) -> None:
    """Compare two client parses of one frame, one read from JSON.

    JSON carries float32 values in their shortest decimal form. The client
    keeps polyline vertices as Float64Array, so those differ from the GLB
    read by float32 rounding; every other value must be identical.
    """
    if isinstance(theirs, dict) and theirs.get("$typed") == "Float64Array":
        assert mine["$typed"] == "Float64Array" and mine["length"] == theirs["length"], path
        assert np.allclose(mine["values"], theirs["values"], rtol=1e-7, atol=0), path
    elif isinstance(theirs, dict):
        assert isinstance(mine, dict) and mine.keys() == theirs.keys(), path
        for key in theirs:
            assert_same_parse(mine[key], theirs[key], f"{path}.{key}")
    elif isinstance(theirs, list):
        assert isinstance(mine, list) and len(mine) == len(theirs), path
        for index, (a, b) in enumerate(zip(mine, theirs)):
            assert_same_parse(a, b, f"{path}[{index}]")
    else:
        assert mine == theirs, path


def sha(array: np.ndarray | bytes) -> str:
    data = array if isinstance(array, bytes) else np.ascontiguousarray(array).tobytes()
    return hashlib.sha256(data).hexdigest()


# ------------------------------------------------------------ logs


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


def update(
    t: float,
    *,
    points: int = 10,
    update_type: str = "SNAPSHOT",
    streams: tuple[str, ...] = ("/vehicle_pose", "/points", "/speed"),
) -> dict[str, Any]:
    """A state update at time ``t`` carrying some of three streams."""
    stream_set: dict[str, Any] = {"timestamp": t}
    if "/vehicle_pose" in streams:
        stream_set["poses"] = {
            "/vehicle_pose": {"timestamp": t, "position": [t, 0.0, 0.0], "orientation": [0.0, 0.0, 0.0]}
        }
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
    """Write a log directory in the reference layout (plainly, not as the product's writer does); return it."""
    directory.mkdir(parents=True, exist_ok=True)
    (directory / f"{METADATA_NUMBER}-frame{fmt.suffix}").write_bytes(
        encode({"type": "xviz/metadata", "data": meta or metadata()}, fmt)
    )
    spans = []
    for i, data in enumerate(updates):
        (directory / f"{file_number(i)}-frame{fmt.suffix}").write_bytes(
            encode({"type": "xviz/state_update", "data": data}, fmt)
        )
        spans.append(update_span(data))
    if index:
        (directory / INDEX_FILE).write_text(json.dumps(index_document(spans)))
    return directory


def write_demo(directory: Path, duration: float = 0.5, fmt: Format = Format.BINARY) -> Path:
    """The built-in demo drive, ``duration`` seconds of it, written as a static log by ``convert``."""
    import io

    from xviz_server.convert import convert

    convert("demo", Path("demo"), directory, fmt=fmt, options={"duration": duration}, processes=1, out=io.StringIO())
    return directory


def ten_hz(count: int, start: float = 100.0, **kwargs: Any) -> list[dict[str, Any]]:
    return [update(round(start + i / 10, 3), **kwargs) for i in range(count)]


def clean_env(**extra: str) -> dict[str, str]:
    """This process's environment without its ``XVIZ_*`` variables, and ``extra``."""
    return {**{k: v for k, v in os.environ.items() if not k.startswith("XVIZ_")}, **extra}


def run_cli(*args: str, **env: str) -> subprocess.CompletedProcess[str]:
    """``xviz-server ARGS`` run to its end (60 s at most) with the variables ``env`` and no others of ours."""
    return subprocess.run(
        [sys.executable, "-m", "xviz_server", *args], capture_output=True, text=True, env=clean_env(**env), timeout=60
    )


@contextlib.asynccontextmanager
async def running_server(data_dir: Path | Sequence[Path | str] | None, **settings: Any) -> AsyncIterator[XVIZServer]:
    """An XVIZ server on a free loopback port, serving one data directory or several (directories, ``s3://`` URLs).

    It is handed over once its catalog has found and indexed every log there is (unless ``settled=False``).
    """
    settled = settings.pop("settled", True)
    async with XVIZServer(Settings(host="127.0.0.1", port=0, data_dir=data_dir, **settings)) as server:
        if settled:
            await asyncio.wait_for(server.indexer.settled(), 60)
        yield server


async def eventually(check: Callable[[], Any], timeout: float = 30.0) -> None:
    """Wait until ``check()`` is true (awaited when it gives an awaitable), polling; fail after ``timeout`` s.

    The way a test waits for the server to get somewhere: on a condition, never a fixed sleep, with a deadline
    generous enough that no load on the machine reaches it."""
    deadline = time.monotonic() + timeout
    while not await _checked(check):
        assert time.monotonic() < deadline, "not within the time allowed"
        await asyncio.sleep(0.05)


async def _checked(check: Callable[[], Any]) -> Any:
    result = check()
    return await result if inspect.isawaitable(result) else result


def http_get(port: int, path: str, method: str = "GET", **headers: str) -> tuple[int, dict[str, str], bytes]:
    """A plain HTTP GET (or ``method``) to a server on loopback: status, headers, body (as sent, not decoded); blocking."""
    request = urllib.request.Request(f"http://127.0.0.1:{port}{path}", headers=headers, method=method)
    try:
        with urllib.request.urlopen(request, timeout=30) as response:
            return response.status, dict(response.headers), response.read()
    except urllib.error.HTTPError as error:
        return error.code, dict(error.headers), error.read()


async def start_serving(*args: str, **env: str) -> tuple[asyncio.subprocess.Process, int, list[str]]:
    """``xviz-server serve --port 0 ARGS``, once it listens: the process, its port and its log lines so far."""
    process = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "xviz_server",
        "serve",
        "--port",
        "0",
        *args,
        stderr=asyncio.subprocess.PIPE,
        env=clean_env(**env),
    )
    assert process.stderr is not None
    lines = []
    while True:
        line = (await asyncio.wait_for(process.stderr.readline(), 30)).decode()
        assert line, "the server exited: " + "".join(lines)
        lines.append(line)
        if listening := re.search(r"listening on wss?://[^ ]+:(\d+)/", line):
            return process, int(listening[1]), lines


async def stop_serving(process: asyncio.subprocess.Process, lines: list[str]) -> str:
    assert process.stderr is not None
    process.terminate()
    lines.append((await asyncio.wait_for(process.stderr.read(), 30)).decode())
    await process.wait()
    return "".join(lines)


class Client:
    """A scripted XVIZ client over a real WebSocket."""

    def __init__(self, websocket: ClientConnection) -> None:
        self.websocket = websocket

    async def recv(self, timeout: float = 30) -> dict[str, Any]:
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


async def paused_viewer(server: XVIZServer, path: str) -> ClientConnection:
    """A client that connected to ``path`` and then stopped reading its socket."""
    websocket = await connect(f"ws://127.0.0.1:{server.port}{path}", max_size=None, max_queue=1)
    websocket.transport.pause_reading()
    return websocket


#: The most any process of a served server may grow by while it works (its peak RSS over its RSS once warm).
GROWTH = 160 << 20


def _status(pid: int, field: str) -> int:
    """A ``/proc/PID/status`` field in bytes (``VmRSS``, ``VmHWM``: the peak RSS); 0 for a process gone."""
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return 0
    match = re.search(rf"^{field}:\s+(\d+) kB", text, re.MULTILINE)
    return int(match.group(1)) * 1024 if match else 0


def _family(pid: int) -> list[int]:
    """``pid`` and every process below it (the fork server and the worker processes)."""
    found, queue = [], [pid]
    while queue:
        current = queue.pop()
        found.append(current)
        for task in Path(f"/proc/{current}/task").glob("*/children"):
            try:
                queue += [int(child) for child in task.read_text().split()]
            except OSError:
                pass
    return found


class Served:
    """``xviz-server serve`` run as a process on port 0, and what it uses."""

    def __init__(self, process: asyncio.subprocess.Process, port: int, lines: list[str]) -> None:
        self.process, self.port, self.lines = process, port, lines

    async def get(self, path: str) -> tuple[int, str]:
        status, _, body = await asyncio.to_thread(http_get, self.port, path)
        return status, body.decode()

    async def logs(self) -> dict[str, dict[str, Any]]:
        status, body = await self.get("/api/logs")
        assert status == 200, body
        return {log["name"]: log for log in json.loads(body)["logs"]}

    async def session(self, log: str) -> list[dict[str, Any]]:
        """Every message of a session that opens ``log`` and plays it all: the error, or metadata and frames."""
        async with connect(f"ws://127.0.0.1:{self.port}/?log={log}", max_size=None, open_timeout=30) as websocket:
            viewer = Client(websocket)
            first = await viewer.recv(120)
            if first["type"] != "xviz/metadata":
                return [first]
            await viewer.send("transform_log", {"id": "all"})
            return [first, *await viewer.until("transform_log_done", "all", timeout=120)]

    def rss(self) -> dict[int, int]:
        return {pid: _status(pid, "VmRSS") for pid in _family(self.process.pid)}

    def peaks(self) -> dict[int, int]:
        return {pid: _status(pid, "VmHWM") for pid in _family(self.process.pid)}

    def holds(self, peer_port: int) -> bool:
        """Whether the server still has a socket open to the loopback client on ``peer_port``.

        Read from ``/proc/net/tcp``: a socket the server closed may linger in
        the kernel, orphaned (its inode 0), until it has told a peer that
        does not read; the server no longer holds it.
        """
        ours, theirs = f":{self.port:04X}", f":{peer_port:04X}"
        with open("/proc/net/tcp") as table:
            next(table)
            for line in table:
                fields = line.split()
                if fields[1].endswith(ours) and fields[2].endswith(theirs) and fields[9] != "0":
                    return True
        return False


@contextlib.asynccontextmanager
async def served(root: Path | str, *flags: str, **env: str) -> AsyncIterator[Served]:
    """``xviz-server serve --data-dir ROOT FLAGS`` as a process with ``env``, its log read as it comes; stopped on exit."""
    process, port, lines = await start_serving("--data-dir", str(root), *flags, **env)
    assert process.stderr is not None

    async def drain() -> None:
        async for line in process.stderr:  # type: ignore[union-attr]
            lines.append(line.decode())

    draining = asyncio.ensure_future(drain())
    try:
        yield Served(process, port, lines)
    finally:
        if process.returncode is None:
            process.terminate()
            try:
                await asyncio.wait_for(process.wait(), 20)
            except asyncio.TimeoutError:
                process.kill()
                await process.wait()
        draining.cancel()


async def foxglove_client(url: str, subprotocol: str, *sends: str, options: tuple[str, ...] = ()) -> dict[str, Any]:
    """What the published Foxglove client (``@foxglove/ws-protocol``, ``interop/foxglove-client.js``) got from ``url``."""
    node = shutil.which("node")
    assert node, "node is required for the interop tests"
    assert (INTEROP / "node_modules" / "@foxglove" / "ws-protocol").is_dir(), "run `npm ci --prefix tests/interop`"
    args = [
        node,
        str(INTEROP / "foxglove-client.js"),
        url,
        subprotocol,
        *options,
        *(item for text in sends for item in ("--send", text)),
    ]
    process = await asyncio.create_subprocess_exec(*args, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    stdout, stderr = await asyncio.wait_for(process.communicate(), 60)
    assert process.returncode == 0, stderr.decode()
    result: dict[str, Any] = json.loads(stdout)
    return result


async def foxglove_opened(
    websocket: ClientConnection, timeout: float = 10
) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """A Foxglove session's opening: ``serverInfo``, then (for a recorded log) the log's start time as a time message,
    checked, then ``advertise``; the server's info and the channels."""
    info = json.loads(await asyncio.wait_for(websocket.recv(), timeout))
    following = await asyncio.wait_for(websocket.recv(), timeout)
    if "dataStartTime" in info:
        start = info["dataStartTime"]["sec"] * 10**9 + info["dataStartTime"]["nsec"]
        assert following == struct.pack("<BQ", 0x02, start)
        following = await asyncio.wait_for(websocket.recv(), timeout)
    advertise = json.loads(following)
    assert info["op"] == "serverInfo" and advertise["op"] == "advertise"
    return info, advertise["channels"]


async def close_received(websocket: ClientConnection, timeout: float = 15) -> Close:
    """The close frame the server ended ``websocket`` with, every message before it read and dropped."""
    with pytest.raises(ConnectionClosed) as closed:
        while True:
            await asyncio.wait_for(websocket.recv(), timeout)
    assert closed.value.rcvd is not None, "the connection ended without a close frame"
    return closed.value.rcvd


def timestamps(messages: list[dict[str, Any]]) -> list[float]:
    """Timestamps of the state updates among ``messages``."""
    return [m["data"]["updates"][0]["timestamp"] for m in messages if m["type"] == "xviz/state_update"]


# ------------------------------------------------------------ the published client


def xviz_decode(paths: list[Path]) -> list[dict]:
    """Decode files in order with @xviz/parser; one result per file."""
    node = shutil.which("node")
    assert node, "node is required for the interop tests"
    assert (INTEROP / "node_modules" / "@xviz" / "parser").is_dir(), (
        "the published client is not installed: run `npm ci --prefix tests/interop` (scripts/test.sh does it)"
    )
    result = subprocess.run(
        [node, str(INTEROP / "xviz-decode.js"), *map(str, paths)],
        capture_output=True,
        text=True,
        check=True,
        timeout=300,
    )
    lines = [json.loads(line) for line in result.stdout.splitlines()]
    assert len(lines) == len(paths), result.stderr
    return lines


def xviz_write(source: Path, **targets: Path) -> None:
    """Write the log in ``source`` again with @xviz/io's writers, one directory per format.

    ``targets`` maps @xviz/io format names (``BINARY_PBE``, ``BINARY_GLB``,
    ``JSON_STRING``) to output directories.
    """
    node = shutil.which("node")
    assert node, "node is required for the interop tests"
    subprocess.run(
        [node, str(INTEROP / "xviz-write.js"), str(source), *(f"{fmt}:{out}" for fmt, out in targets.items())],
        check=True,
        capture_output=True,
        timeout=300,
    )


def xviz_validate(paths: Sequence[Path]) -> list[dict[str, Any]]:
    """Validate files with the published validator (``validate.js``); one ``{"file", "type", "errors"}`` per file.

    A file that @xviz/io cannot read gives ``{"file", "error"}`` instead.
    """
    node = shutil.which("node")
    assert node, "node is required for the interop tests"
    assert (INTEROP / "node_modules" / "@xviz" / "schema").is_dir(), (
        "the published validator is not installed: run `npm ci --prefix tests/interop`"
    )
    result = subprocess.run(
        [node, str(INTEROP / "validate.js"), *map(str, paths)], capture_output=True, text=True, timeout=300
    )
    lines = [json.loads(line) for line in result.stdout.splitlines()]
    assert len(lines) == len(paths), result.stderr
    return lines


def xviz_validate_instances(cases: Sequence[tuple[str, Any]], directory: Path) -> list[dict[str, Any]]:
    """Validate ``(schema name, JSON value)`` pairs with the published validator; one ``{"schema", "errors"}`` each.

    The cases go through a file in ``directory``.
    """
    node = shutil.which("node")
    assert node, "node is required for the interop tests"
    listing = directory / "instances.json"
    listing.write_text(json.dumps([{"schema": name, "instance": instance} for name, instance in cases]))
    command = [node, str(INTEROP / "validate.js"), "--instances", str(listing)]
    result = subprocess.run(command, capture_output=True, text=True, timeout=300)
    lines = [json.loads(line) for line in result.stdout.splitlines()]
    assert len(lines) == len(cases), result.stderr
    return lines


@dataclass(frozen=True)
class SessionResult:
    """What the client received, and how the driver ended.

    ``messages`` holds one dict per message, in arrival order, as the driver
    prints them: ``index``, ``kind``, ``bytes``, ``type`` and ``raw`` /
    ``parsed`` (or, for state updates in brief mode, ``timestamp``,
    ``streams`` and ``poses``). ``summary`` is the driver's closing
    ``{"messages", "by_type", "errors", "closed"}``, or None when it printed
    none (a bad command line or script, or a crash: see ``stderr``).
    """

    messages: list[dict[str, Any]]
    summary: dict[str, Any] | None
    returncode: int
    stderr: str

    @property
    def ok(self) -> bool:
        """Whether every step of the script completed."""
        return self.returncode == 0

    def of_type(self, type_: str) -> list[dict[str, Any]]:
        """The messages of one envelope type, such as ``"xviz/state_update"``."""
        return [message for message in self.messages if message["type"] == type_]


def run_xviz_session(
    url: str, script: list[dict[str, Any]], *, brief: bool = False, validate: bool = False, timeout: float = 60
) -> SessionResult:
    """Run ``script`` against the server at ``url``, blocking until the driver exits.

    With ``validate``, the published validator checks every message received:
    those it refuses are ``"schema"`` errors in the summary.

    ``timeout`` bounds the whole run in seconds; past it the driver is killed
    and ``subprocess.TimeoutExpired`` raised. Each wait step has its own,
    shorter limit (30 s, or the step's ``timeout_ms``) after which the driver
    reports and fails.
    """
    command = _command(url, brief, validate)
    completed = subprocess.run(command, input=_encode(script), capture_output=True, timeout=timeout)
    return _result(completed.stdout, completed.stderr, completed.returncode)


async def run_xviz_session_async(
    url: str, script: list[dict[str, Any]], *, brief: bool = False, validate: bool = False, timeout: float = 60
) -> SessionResult:
    """Run ``script`` against the server at ``url`` without blocking the event loop.

    Same contract as :func:`run_xviz_session`.
    """
    command = _command(url, brief, validate)
    process = await asyncio.create_subprocess_exec(
        *command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    try:
        stdout, stderr = await asyncio.wait_for(process.communicate(_encode(script)), timeout)
    except asyncio.TimeoutError:
        process.kill()
        await process.wait()
        raise subprocess.TimeoutExpired(command, timeout) from None
    return _result(stdout, stderr, process.returncode)


def _command(url: str, brief: bool, validate: bool) -> list[str]:
    node = shutil.which("node")
    assert node, "node is required for the interop tests"
    assert (INTEROP / "node_modules" / "ws").is_dir(), (
        "the client libraries are not installed: run `npm ci --prefix tests/interop` (scripts/test.sh does it)"
    )
    # The script goes on stdin, so no command line limits its size.
    options = [*(["--brief"] if brief else []), *(["--validate"] if validate else [])]
    return [node, str(DRIVER), url, "--script-file", "-", *options]


def _encode(script: list[dict[str, Any]]) -> bytes:
    return json.dumps(script).encode()


def _result(stdout: bytes, stderr: bytes, returncode: int) -> SessionResult:
    lines = [json.loads(line) for line in stdout.decode().splitlines()]
    summary = lines.pop()["summary"] if lines and "summary" in lines[-1] else None
    return SessionResult(lines, summary, returncode, stderr.decode())
