"""scripts/serve.sh, the README's first command: it installs only what changed, and says at once
that the port is taken. Run in this checkout, with its own .venv (as scripts/test.sh made it)."""

from __future__ import annotations

import re
import signal
import socket
import subprocess
from pathlib import Path

import pytest

from helpers import clean_env

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "scripts" / "serve.sh"
STAMPS = REPO / ".venv" / "serve-stamps"


def stamps() -> dict[str, tuple[int, str]]:
    """Each stamp's modification time and content: an install rewrites its stamp."""
    return (
        {path.name: (path.stat().st_mtime_ns, path.read_text()) for path in STAMPS.glob("*")} if STAMPS.is_dir() else {}
    )


def start(*args: str) -> tuple[subprocess.Popen[str], str]:
    """serve.sh ARGS until the server listens: the process and what it printed so far."""
    process = subprocess.Popen(
        [str(SCRIPT), *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=clean_env(),
        start_new_session=True,
    )
    assert process.stdout is not None
    output = []
    for line in process.stdout:  # ends when the process does; the test's timeout bounds the installs
        output.append(line)
        if re.search(r"the viewer page: http://127\.0\.0\.1:\d+/$", line):  # after "listening on ws://..."
            return process, "".join(output)
    raise AssertionError("serve.sh exited before listening:\n" + "".join(output))


def stop(process: subprocess.Popen[str]) -> None:
    process.send_signal(signal.SIGTERM)  # serve.sh execs the server: this is the server
    assert process.wait(timeout=60) == 0


def test_a_port_in_use_is_said_before_anything_is_installed():
    before = stamps()
    with socket.create_server(("127.0.0.1", 0)) as taken:
        port = taken.getsockname()[1]
        result = subprocess.run(
            [str(SCRIPT), "--port", str(port)], capture_output=True, text=True, timeout=60, env=clean_env()
        )
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr == (
        f"serve.sh: cannot listen on 127.0.0.1:{port}: address already in use; another process "
        "listens there: choose a free port with --port (XVIZ_PORT)\n"
    )
    assert stamps() == before


@pytest.mark.slow
def test_a_second_start_installs_nothing():
    first, _ = start("--port", "0")
    stop(first)
    installed = stamps()
    assert sorted(installed) == ["package", "viewer"]
    second, output = start("--port", "0")
    stop(second)
    assert stamps() == installed and "viewer bundle in" not in output  # no install, no build
