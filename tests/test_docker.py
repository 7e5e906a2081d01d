"""The Docker image's steps, run outside Docker: install, entry point, health check, compose file.

There is no Docker engine on the development machine; the Dockerfile's build
stage runs docker/install.sh and the container runs docker/entrypoint.sh,
so running those scripts here exercises what the image does.
"""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from helpers import ten_hz, write_log

DOCKER = Path(__file__).resolve().parents[1] / "docker"


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.fixture(scope="module")
def image_prefix(tmp_path_factory) -> Path:
    """What the build stage makes: a virtual environment with the package installed from the repository."""
    prefix = tmp_path_factory.mktemp("image") / "opt-xviz"
    result = subprocess.run([str(DOCKER / "install.sh"), str(prefix)], capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("xviz-server ")
    return prefix


def test_dockerfile_uses_the_scripts_and_the_conventions():
    dockerfile = (DOCKER / "Dockerfile").read_text()
    assert "RUN /src/docker/install.sh /opt/xviz" in dockerfile
    assert 'ENTRYPOINT ["entrypoint.sh"]' in dockerfile and 'HEALTHCHECK' in dockerfile and "EXPOSE 3000" in dockerfile
    assert re.search(r"^USER xviz$", dockerfile, re.M)
    stages = re.split(r"^FROM ", dockerfile, flags=re.M)[1:]
    assert len(stages) == 2 and "gcc" in stages[0] and "gcc" not in stages[1]  # no compiler in the final image


def test_compose_file_follows_the_compose_specification():
    result = subprocess.run(
        [sys.executable, "-m", "check_jsonschema", "--builtin-schema", "vendor.compose-spec", str(DOCKER / "compose.yaml")],
        capture_output=True, text=True,
    )
    assert result.returncode == 0, result.stdout + result.stderr


def test_entrypoint_serves_reports_health_and_stops_on_sigterm(image_prefix: Path, tmp_path: Path):
    write_log(tmp_path / "data" / "drive", ten_hz(5))
    port = free_port()
    env = {**os.environ, "PATH": f"{image_prefix / 'bin'}:{DOCKER}:{os.environ['PATH']}", "XVIZ_HOST": "127.0.0.1",
           "XVIZ_PORT": str(port), "XVIZ_DATA_DIR": str(tmp_path / "data"), "XVIZ_LOG_FORMAT": "json"}
    server = subprocess.Popen([str(DOCKER / "entrypoint.sh")], env=env, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while subprocess.run([str(DOCKER / "healthcheck.sh")], env=env, capture_output=True).returncode != 0:
            assert time.monotonic() < deadline and server.poll() is None, "the server never became healthy"
            time.sleep(0.3)
        probe = subprocess.run([str(image_prefix / "bin" / "xviz-server"), "probe", f"ws://127.0.0.1:{port}/drive"],
                               capture_output=True, text=True, timeout=60)
        assert probe.returncode == 0, probe.stdout
        server.send_signal(signal.SIGTERM)
        assert server.wait(20) == 0
    finally:
        if server.poll() is None:
            server.kill()
    log = server.stderr.read()
    assert '"event":"session end"' in log and '"reason":"1000"' in log  # JSON log lines
