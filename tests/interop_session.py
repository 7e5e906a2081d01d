"""Run a scripted XVIZ session against a server with the published client.

``tests/interop/xviz-session.js`` connects to a WebSocket URL with the ``ws``
package, performs a script of client actions and decodes every message it
receives with @xviz/parser 1.0.13, as streetscape.gl does; its header lists
the steps. This module runs it in a subprocess and reads back its report::

    result = await run_xviz_session_async(url, [
        {"wait": "metadata"},
        {"send_transform_log": {"id": "1", "from_start": 0.0, "to_start": 1.0}},
        {"wait": "done", "id": "1"},
    ])
    assert result.ok, result.stderr
    updates = result.of_type("xviz/state_update")

Use the async version when the server under test runs in the test's own
event loop; the blocking one would stall it.
"""

from __future__ import annotations

import asyncio
import json
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Any

INTEROP = Path(__file__).parent / "interop"
DRIVER = INTEROP / "xviz-session.js"


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
    url: str, script: list[dict[str, Any]], *, brief: bool = False, timeout: float = 60
) -> SessionResult:
    """Run ``script`` against the server at ``url``, blocking until the driver exits.

    ``timeout`` bounds the whole run in seconds; past it the driver is killed
    and ``subprocess.TimeoutExpired`` raised. Each wait step has its own,
    shorter limit (30 s, or the step's ``timeout_ms``) after which the driver
    reports and fails.
    """
    command = _command(url, brief)
    completed = subprocess.run(command, input=_encode(script), capture_output=True, timeout=timeout)
    return _result(completed.stdout, completed.stderr, completed.returncode)


async def run_xviz_session_async(
    url: str, script: list[dict[str, Any]], *, brief: bool = False, timeout: float = 60
) -> SessionResult:
    """Run ``script`` against the server at ``url`` without blocking the event loop.

    Same contract as :func:`run_xviz_session`.
    """
    command = _command(url, brief)
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


def _command(url: str, brief: bool) -> list[str]:
    node = shutil.which("node")
    assert node, "node is required for the interop tests"
    assert (INTEROP / "node_modules" / "ws").is_dir(), (
        "the client libraries are not installed: run `npm ci --prefix tests/interop` "
        "(scripts/test.sh does it)"
    )
    # The script goes on stdin, so no command line limits its size.
    return [node, str(DRIVER), url, "--script-file", "-", *(["--brief"] if brief else [])]


def _encode(script: list[dict[str, Any]]) -> bytes:
    return json.dumps(script).encode()


def _result(stdout: bytes, stderr: bytes, returncode: int) -> SessionResult:
    lines = [json.loads(line) for line in stdout.decode().splitlines()]
    summary = lines.pop()["summary"] if lines and "summary" in lines[-1] else None
    return SessionResult(lines, summary, returncode, stderr.decode())
