"""An operator's mistakes at start-up: each ends in one line saying what to set, never a traceback.

The real ``xviz-server`` command runs against real sockets, folders and files.
"""

from __future__ import annotations

import asyncio
import socket
from pathlib import Path

import pytest

from helpers import client, run_cli, running_server, ten_hz, write_log


@pytest.fixture
def root(tmp_path: Path) -> Path:
    write_log(tmp_path / "logs" / "drive", ten_hz(3))
    return tmp_path / "logs"


def one_line_error(result, *parts: str) -> None:
    assert "Traceback" not in result.stderr, result.stderr
    errors = [line for line in result.stderr.splitlines() if line.startswith(f"xviz-server {result.args[3]}:")]
    assert len(errors) == 1, result.stderr
    for part in parts:
        assert part in errors[0], errors[0]


def test_a_port_in_use_stops_the_server_at_once_saying_to_choose_another(root: Path):
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        port = holder.getsockname()[1]
        result = run_cli("serve", "--data-dir", str(root), "--host", "127.0.0.1", "--port", str(port))
    assert result.returncode == 2
    one_line_error(result, f"cannot listen on 127.0.0.1:{port}: address already in use", "--port (XVIZ_PORT)")


def test_an_address_of_no_interface_stops_the_server_saying_to_set_the_host(root: Path):
    result = run_cli("serve", "--data-dir", str(root), "--port", "0", XVIZ_HOST="192.0.2.1")  # TEST-NET-1
    assert result.returncode == 2
    one_line_error(result, "cannot listen on 192.0.2.1:0", "--host (XVIZ_HOST)")


def test_a_record_folder_that_cannot_be_written_stops_the_server_before_it_serves(root: Path, tmp_path: Path):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    result = run_cli("serve", "--data-dir", str(root), "--port", "0", "--record", str(blocker / "recordings"))
    assert result.returncode == 2
    one_line_error(result, f"--record {blocker / 'recordings'}: cannot write there", "writable folder")
    assert "listening" not in result.stderr


def test_convert_into_a_place_that_cannot_be_written_says_where_and_why(tmp_path: Path):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    result = run_cli("convert", "demo", "demo", str(blocker / "out"))
    assert result.returncode == 1
    one_line_error(result, f"{blocker / 'out'}: Not a directory")


async def test_an_empty_store_is_served_saying_so_and_a_log_added_later_is_found(tmp_path: Path, caplog):
    store = tmp_path / "store"
    store.mkdir()
    async with running_server(store) as server:
        assert f"no logs under {store} yet" in caplog.text
        await asyncio.to_thread(write_log, store / "late", ten_hz(3))
        async with client(server, "/?log=late") as viewer:
            metadata = await viewer.recv()
            assert metadata["type"] == "xviz/metadata"
