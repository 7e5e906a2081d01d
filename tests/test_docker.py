"""The Docker image's steps, run outside Docker: install, entry point, health check, compose file.

The Dockerfile's build stage runs docker/install.sh and the container runs
docker/entrypoint.sh and ``xviz-server healthcheck --pid 1``, so running those
here exercises what the image does; scripts/test-image.sh builds and runs
the image itself where a container engine can run.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from helpers import ten_hz, write_log

pytestmark = pytest.mark.slow

DOCKER = Path(__file__).resolve().parents[1] / "docker"


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.fixture(scope="module")
def image_prefix(tmp_path_factory) -> Path:
    """What the build stage makes, from a checkout holding a stale build/ folder and other leftovers."""
    checkout = tmp_path_factory.mktemp("checkout")
    repo = DOCKER.parent
    for name in ("pyproject.toml", "setup.py", "README.md", "xviz_server", "providers", "schema", "docker"):
        copy = shutil.copytree if (repo / name).is_dir() else shutil.copy
        copy(repo / name, checkout / name)
    (checkout / "build" / "lib" / "xviz_server").mkdir(parents=True)
    (checkout / "build" / "lib" / "xviz_server" / "stale_module.py").write_text("raise SystemExit('stale')\n")
    prefix = tmp_path_factory.mktemp("image") / "opt-xviz"
    result = subprocess.run(
        [str(checkout / "docker" / "install.sh"), str(prefix)], capture_output=True, text=True, timeout=900
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("xviz-server ")
    return prefix


def test_install_keeps_only_what_serving_uses(image_prefix: Path):
    (site,) = image_prefix.glob("lib/python3*/site-packages")
    assert not list(site.glob("xviz_server/**/stale_module.py"))  # only the files the package declares
    assert not [p.name for p in site.iterdir() if p.name.split("-")[0] in ("pip", "setuptools", "pkg_resources")]
    assert (site / "numpy").is_dir() and (site / "jsonschema").is_dir()
    assert not list(site.glob("**/tests")) and not list(site.glob("**/*.pyi"))  # numpy's, jsonschema's, ...
    assert not list(site.glob("numpy/**/*.h")) and not (site / "numpy" / "f2py").exists()
    assert not (image_prefix / "bin" / "pip").exists()
    # Bags and MCAP files are read (the ros extra); Pillow's formats serving never uses are gone.
    assert (
        (site / "rosbags").is_dir()
        and (site / "apsw").is_dir()
        and not (site / "apsw" / "sqlite_extra_binaries").exists()
    )
    assert not list(site.glob("PIL/_avif.*")) and not list(site.glob("pillow.libs/libavif-*"))
    if shutil.which("readelf"):  # extension modules without debug info or static symbols (install.sh strips them)
        (uvloop,) = site.glob("uvloop/loop.*.so")
        sections = subprocess.run(
            ["readelf", "-S", "-W", str(uvloop)], capture_output=True, text=True, check=True
        ).stdout
        assert ".debug_info" not in sections and ".symtab" not in sections


def test_dockerfile_uses_the_scripts_and_the_conventions():
    dockerfile = (DOCKER / "Dockerfile").read_text()
    assert "RUN /src/docker/install.sh /opt/xviz" in dockerfile
    assert 'ENTRYPOINT ["entrypoint.sh"]' in dockerfile and "EXPOSE 3000" in dockerfile
    assert 'CMD ["xviz-server", "healthcheck", "--pid", "1"]' in dockerfile
    assert re.search(r"^USER xviz$", dockerfile, re.M)
    assert re.search(r"^ARG BASE_IMAGE=python:3\.\d+-slim-bookworm$", dockerfile, re.M)  # a pinned release
    assert re.search(r"^ARG NODE_IMAGE=node:\d+-bookworm-slim$", dockerfile, re.M)
    stages = re.split(r"^FROM ", dockerfile, flags=re.M)[1:]
    assert [stage.split()[0] for stage in stages] == ["${NODE_IMAGE}", "${BASE_IMAGE}", "${BASE_IMAGE}"]
    assert "RUN /src/scripts/build-viewer.sh /viewer" in dockerfile  # the viewer built one way, by its script
    # No compiler: the build stage installs only binutils (strip), and the image nothing; the demo when nothing is mounted.
    assert [line for line in dockerfile.splitlines() if "apt-get" in line] == [
        "RUN apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends binutils >/dev/null"
    ]
    assert "apt-get" in stages[1] and "apt-get" not in stages[2] and "XVIZ_DATA_DIR" not in dockerfile


def test_compose_file_follows_the_compose_specification():
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "check_jsonschema",
            "--builtin-schema",
            "vendor.compose-spec",
            str(DOCKER / "compose.yaml"),
        ],
        capture_output=True,
        text=True,
    )
    assert result.returncode == 0, result.stdout + result.stderr


def test_entrypoint_serves_reports_health_and_stops_on_sigterm(image_prefix: Path, tmp_path: Path):
    write_log(tmp_path / "data" / "drive", ten_hz(5))
    port = free_port()
    (tmp_path / "server.toml").write_text(f"port = {port}\n")
    env = {
        **{k: v for k, v in os.environ.items() if not k.startswith("XVIZ_")},
        "PATH": f"{image_prefix / 'bin'}:{DOCKER}:{os.environ['PATH']}",
        "XVIZ_HOST": "127.0.0.1",
        "XVIZ_CONFIG": str(tmp_path / "server.toml"),
        "XVIZ_DATA_DIR": str(tmp_path / "data"),
        "XVIZ_LOG_FORMAT": "json",
    }
    server = subprocess.Popen([str(DOCKER / "entrypoint.sh")], env=env, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    # As the image's HEALTHCHECK runs it: with PID 1's settings, here the entry point's process.
    healthcheck = [str(image_prefix / "bin" / "xviz-server"), "healthcheck", "--pid", str(server.pid)]
    try:
        deadline = time.monotonic() + 60
        while subprocess.run(healthcheck, capture_output=True, timeout=60).returncode != 0:
            assert time.monotonic() < deadline and server.poll() is None, "the server never became healthy"
            time.sleep(0.3)
        probe = subprocess.run(
            [str(image_prefix / "bin" / "xviz-server"), "probe", f"ws://127.0.0.1:{port}/drive"],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert probe.returncode == 0, probe.stdout
        server.send_signal(signal.SIGTERM)
        assert server.wait(20) == 0
    finally:
        if server.poll() is None:
            server.kill()
    log = server.stderr.read()
    assert '"event":"session end"' in log and '"reason":"1000"' in log  # JSON log lines
    gone = subprocess.run(["xviz-server", "healthcheck"], env=env, capture_output=True, text=True, timeout=60)
    assert gone.returncode == 1 and f"unhealthy: http://127.0.0.1:{port}/healthz" in gone.stderr


def test_entrypoint_serves_the_demo_with_nothing_mounted(image_prefix: Path, tmp_path: Path):
    port = free_port()
    env = {
        **{k: v for k, v in os.environ.items() if not k.startswith("XVIZ_")},
        "PATH": f"{image_prefix / 'bin'}:{os.environ['PATH']}",
        "XVIZ_HOST": "127.0.0.1",
        "XVIZ_PORT": str(port),
        "XDG_CACHE_HOME": str(tmp_path / "cache"),
    }
    assert not Path("/data").exists() or not any(Path("/data").iterdir()), "this machine has a /data store"
    server = subprocess.Popen([str(DOCKER / "entrypoint.sh")], env=env, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    try:
        # The demo is made frame by frame on demand: the first second of it.
        probe = [
            str(image_prefix / "bin" / "xviz-server"),
            "probe",
            "--timeout",
            "20",
            "--end",
            "+1",
            f"ws://127.0.0.1:{port}/?log=demo",
        ]
        deadline = time.monotonic() + 60
        while (result := subprocess.run(probe, capture_output=True, text=True, timeout=60)).returncode != 0:
            assert time.monotonic() < deadline and server.poll() is None, result.stdout + result.stderr
            time.sleep(0.3)
    finally:
        server.terminate()
        server.wait(20)
    assert "serving the built-in demo log" in server.stderr.read()
