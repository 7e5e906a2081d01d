"""``xviz-server healthcheck``: the server's own settings, https with TLS, and non-200 as unhealthy."""

from __future__ import annotations

import asyncio
import http.server
import os
import subprocess
import sys
import threading
from pathlib import Path

import trustme

from helpers import running_server, ten_hz, write_log


def healthcheck(*args: str, **env: str) -> subprocess.CompletedProcess:
    clean = {k: v for k, v in os.environ.items() if not k.startswith("XVIZ_")}
    return subprocess.run(
        [sys.executable, "-m", "xviz_server", "healthcheck", *args],
        capture_output=True,
        text=True,
        env={**clean, **env},
        timeout=60,
    )


async def test_https_on_the_port_of_the_configuration_file(tmp_path: Path):
    write_log(tmp_path / "logs" / "drive", ten_hz(2))
    certificate = trustme.CA().issue_cert("example.com")  # a name the check does not ask for
    certfile, keyfile = tmp_path / "cert.pem", tmp_path / "key.pem"
    certificate.cert_chain_pems[0].write_to_path(str(certfile))
    certificate.private_key_pem.write_to_path(str(keyfile))
    async with running_server(tmp_path / "logs", certfile=certfile, keyfile=keyfile) as server:
        config = tmp_path / "server.toml"
        config.write_text(f'port = {server.port}\ncertfile = "{certfile}"\nkeyfile = "{keyfile}"\nhost = "0.0.0.0"\n')
        result = await asyncio.to_thread(healthcheck, "--config", str(config))
        assert result.returncode == 0, result.stderr
        assert result.stdout == f"healthy: https://127.0.0.1:{server.port}/healthz\n"
        plain = await asyncio.to_thread(healthcheck, "--port", str(server.port))  # the wrong scheme
        assert plain.returncode == 1 and plain.stderr.startswith(f"unhealthy: http://127.0.0.1:{server.port}/healthz: ")


def test_any_answer_but_200_is_unhealthy():
    class Failing(http.server.BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            self.send_response(503)
            self.end_headers()
            self.wfile.write(b"worker pool broken\n")

        def log_message(self, *args: object) -> None:
            pass

    with http.server.ThreadingHTTPServer(("127.0.0.1", 0), Failing) as failing:
        thread = threading.Thread(target=failing.serve_forever)
        thread.start()
        try:
            result = healthcheck(XVIZ_PORT=str(failing.server_address[1]))
        finally:
            failing.shutdown()
            thread.join()
    assert result.returncode == 1
    assert (
        result.stderr
        == f"unhealthy: http://127.0.0.1:{failing.server_address[1]}/healthz: HTTP 503 worker pool broken\n"
    )


def test_pid_of_a_process_that_is_not_a_server():
    result = healthcheck("--pid", str(os.getpid()))
    assert result.returncode == 1 and f"--pid {os.getpid()}: not an xviz-server serve process" in result.stderr
