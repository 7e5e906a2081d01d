"""What reaches logs and screens, and unsafe configuration (issue 22, items 9 to 11).

Each case runs the real server on loopback, mostly as the ``xviz-server``
command, and looks at what it really printed.
"""

from __future__ import annotations

import asyncio
import json
import socket
import ssl
import subprocess
import sys
import urllib.error
import urllib.request
from pathlib import Path

import pytest
import trustme
from cryptography.hazmat.primitives import serialization
from websockets.asyncio.client import connect
from websockets.exceptions import InvalidStatus

from helpers import run_cli, running_server, start_serving, stop_serving, ten_hz, write_log
from xviz_server.logfmt import printable, redact_url

TOKEN = "s3cret-Token_42"


@pytest.fixture
def root(tmp_path: Path) -> Path:
    write_log(tmp_path / "logs" / "drive", ten_hz(3))
    return tmp_path / "logs"


def test_redact_url_hides_credential_parameters_only():
    assert redact_url("/?log=demo&token=s3cret") == "/?log=demo&token=REDACTED"
    assert redact_url("/drive?TOKEN=a&%74oken=b&access_token=c&api_key=d&password=e&format=glb") == (
        "/drive?TOKEN=REDACTED&%74oken=REDACTED&access_token=REDACTED&api_key=REDACTED&password=REDACTED&format=glb"
    )
    assert redact_url("/ingest/car") == "/ingest/car"
    assert redact_url("/?log=token") == "/?log=token"  # values are not names


def test_printable_escapes_control_characters():
    assert (
        printable("x=\x1b[31mRED a\rinjected\nline\x7f\x9b\u2028")
        == "x=\\x1b[31mRED a\\rinjected\\nline\\x7f\\x9b\\u2028"
    )
    assert printable("plain text, ünïcode") == "plain text, ünïcode"


@pytest.mark.parametrize("log_format", ["text", "json"])
async def test_no_token_reaches_the_log(root: Path, tmp_path: Path, log_format: str):
    token_file = tmp_path / "viewer-token"
    token_file.write_text(TOKEN + "\n")
    process, port, lines = await start_serving(
        "--data-dir",
        str(root),
        "--log-format",
        log_format,
        "--viewer-token-file",
        str(token_file),
    )
    for path, headers in [
        (f"/drive?token={TOKEN}", {}),
        (f"/?log=drive&token={TOKEN}&secret={TOKEN}", {}),
        (f"/?access_token={TOKEN}&token={TOKEN}&log=drive", {}),
        ("/drive", {"Authorization": f"Bearer {TOKEN}"}),
    ]:
        async with connect(f"ws://127.0.0.1:{port}{path}", additional_headers=headers) as websocket:
            await websocket.recv()
            await websocket.send("{broken")  # an error sent is logged too
            await websocket.recv()
    with pytest.raises(InvalidStatus):  # a wrong token is refused, and not logged either
        async with connect(f"ws://127.0.0.1:{port}/drive?token=wrong-{TOKEN}"):
            pass
    log = await stop_serving(process, lines)
    starts = [line for line in log.splitlines() if "session start" in line]
    assert len(starts) == 4 and all("token=REDACTED" in line for line in starts[:3])
    assert TOKEN not in log


async def test_control_characters_in_the_path_are_escaped_in_the_log(root: Path):
    process, port, lines = await start_serving("--data-dir", str(root))
    request = (
        b"GET /?log=drive&x=\x1b[31mRED&y=a\rinjected&z=\x7f HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\n"
        b"Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n"
    )
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(request)
    await writer.drain()
    assert (await asyncio.wait_for(reader.readline(), 10)).startswith(b"HTTP/1.1 101")
    while not any("session start" in line for line in lines):
        lines.append((await asyncio.wait_for(process.stderr.readline(), 30)).decode())
        assert lines[-1], "the server exited"
    writer.close()
    log = await stop_serving(process, lines)
    (start,) = [line for line in log.splitlines() if "session start" in line]
    assert "x=\\x1b[31mRED&y=a\\rinjected&z=\\x7f" in start
    assert "\x1b" not in log and "\r" not in log


def test_config_hides_the_tokens(tmp_path: Path):
    token_file = tmp_path / "ingest-token"
    token_file.write_text(TOKEN)
    result = run_cli("config", "--ingest-token-file", str(token_file), XVIZ_VIEWER_TOKEN=f"viewer-{TOKEN}")
    assert result.returncode == 0, result.stderr
    assert TOKEN not in result.stdout
    assert "# viewer_token is set (not shown)" in result.stdout and "# ingest_token is set (not shown)" in result.stdout
    assert f'ingest_token_file = "{token_file}"' in result.stdout


def test_token_file_mistakes_are_clear(tmp_path: Path):
    missing = run_cli("serve", "--viewer-token-file", str(tmp_path / "nope"))
    assert missing.returncode == 2 and f"cannot read the token file {tmp_path / 'nope'}: No such file" in missing.stderr
    (tmp_path / "empty").write_text("\n")
    empty = run_cli("serve", "--ingest-token-file", str(tmp_path / "empty"))
    assert empty.returncode == 2 and "must hold one line" in empty.stderr
    both = run_cli("config", "--viewer-token-file", str(tmp_path / "empty"), XVIZ_VIEWER_TOKEN="x")
    assert both.returncode == 2 and "give --viewer-token or --viewer-token-file, not both" in both.stderr
    assert "Traceback" not in missing.stderr + empty.stderr + both.stderr


async def test_metrics_can_require_the_viewer_token(root: Path):
    def status(url: str) -> int:
        try:
            return urllib.request.urlopen(url, timeout=10).status
        except urllib.error.HTTPError as error:
            return error.code

    async with running_server(root, viewer_token=TOKEN, protect_metrics=True) as server:
        base = f"http://127.0.0.1:{server.port}"
        assert await asyncio.to_thread(status, f"{base}/metrics") == 401
        assert await asyncio.to_thread(status, f"{base}/metrics?token={TOKEN}") == 200
        assert await asyncio.to_thread(status, f"{base}/healthz") == 200
    async with running_server(root, viewer_token=TOKEN) as server:  # the default: open, as before
        assert await asyncio.to_thread(status, f"http://127.0.0.1:{server.port}/metrics") == 200
    alone = run_cli("serve", "--protect-metrics")
    assert alone.returncode == 2 and "--protect-metrics needs a viewer token" in alone.stderr


@pytest.fixture(scope="module")
def pems(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A certificate, its key, the key encrypted, another key, and garbage."""
    directory = tmp_path_factory.mktemp("pems")
    authority = trustme.CA()
    certificate = authority.issue_cert("127.0.0.1")
    files = {name: directory / f"{name}.pem" for name in ("cert", "key", "encrypted", "other", "garbage")}
    certificate.cert_chain_pems[0].write_to_path(str(files["cert"]))
    certificate.private_key_pem.write_to_path(str(files["key"]))
    authority.issue_cert("elsewhere").private_key_pem.write_to_path(str(files["other"]))
    files["garbage"].write_bytes(b"\x00not a pem file\n")
    key = serialization.load_pem_private_key(certificate.private_key_pem.bytes(), password=None)
    files["encrypted"].write_bytes(
        key.private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.PKCS8,
            serialization.BestAvailableEncryption(b"secret"),
        )
    )
    for path in files.values():
        path.chmod(0o600)
    return files


@pytest.mark.parametrize(
    "cert, key, message",
    [
        (None, "key", "--keyfile {key} without --certfile: give the certificate too (or neither)"),
        ("cert", "missing", "--keyfile {missing}: No such file or directory"),
        ("missing", "key", "--certfile {missing}: No such file or directory"),
        ("cert", "encrypted", "--keyfile {encrypted}: the key is encrypted"),
        ("garbage", "key", "--certfile {garbage}: no PEM certificate in it"),
        ("cert", "garbage", "--keyfile {garbage}: no PEM private key in it"),
        ("cert", "other", "--certfile {cert}, --keyfile {other}: the key is not the certificate's key"),
        ("cert", None, "--certfile {cert}: no PEM private key in it"),
    ],
)
def test_unusable_tls_files_stop_the_server_naming_the_file(
    pems: dict[str, Path], root: Path, cert: str | None, key: str | None, message: str
):
    files = {**pems, "missing": pems["cert"].parent / "missing.pem"}
    args = ["serve", "--data-dir", str(root), "--port", "0"]
    if cert:
        args += ["--certfile", str(files[cert])]
    if key:
        args += ["--keyfile", str(files[key])]
    result = run_cli(*args)
    assert result.returncode == 2
    assert message.format(**files) in result.stderr
    assert "Traceback" not in result.stderr and "listening" not in result.stderr


async def test_a_key_readable_by_everyone_is_served_with_a_warning(pems: dict[str, Path], root: Path, caplog):
    pems["key"].chmod(0o644)
    try:
        async with running_server(root, certfile=pems["cert"], keyfile=pems["key"]) as server:
            context = ssl.create_default_context()
            context.check_hostname, context.verify_mode = False, ssl.CERT_NONE

            def handshake() -> str | None:
                with socket.create_connection(("127.0.0.1", server.port)) as raw, context.wrap_socket(raw) as tls:
                    return tls.version()

            assert await asyncio.to_thread(handshake) in ("TLSv1.2", "TLSv1.3")
    finally:
        pems["key"].chmod(0o600)
    assert f"the TLS key {pems['key']} can be read by every user of this machine" in caplog.text
    caplog.clear()
    async with running_server(root, certfile=pems["cert"], keyfile=pems["key"]):
        pass
    assert "can be read by every user" not in caplog.text


def test_json_log_lines_escape_what_json_leaves_raw():
    line = subprocess.run(
        [
            sys.executable,
            "-c",
            "import logging; from xviz_server.logfmt import configure_logging, log_event;"
            "configure_logging('json'); log_event(logging.getLogger('t'), 'x', path='/?a=\\x9b31m\\x7f')",
        ],
        capture_output=True,
        text=True,
        timeout=30,
    ).stderr
    assert "\x9b" not in line and "\x7f" not in line
    assert json.loads(line)["path"] == "/?a=\\x9b31m\\x7f"
