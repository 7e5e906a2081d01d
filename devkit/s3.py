"""A real S3 API on loopback for tests and benchmarks: moto's standalone server, and uploads to it.

moto's server speaks the S3 HTTP API with signatures, so the server's client
code is the same as against AWS or MinIO. The credentials are made up: moto
accepts any.
"""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
import time
from collections.abc import AsyncIterator, Iterator
from pathlib import Path

import boto3
import pytest

from devkit.tcpproxy import Proxy, running_proxy

__all__ = ["ACCESS_KEY", "SECRET_KEY", "MotoS3", "moto_process", "store_env", "proxied"]

ACCESS_KEY = "AKIAXVIZTESTKEY00001"
#: A made-up secret that tests look for in every output: it must never show.
SECRET_KEY = "xvizTestSecret/d0NotPrint+Kq3vYw8sZ1"


def store_env(endpoint: str) -> dict[str, str]:
    """The AWS variables that point a client at ``endpoint`` with the test credentials."""
    return {
        "AWS_ENDPOINT_URL": endpoint,
        "AWS_ACCESS_KEY_ID": ACCESS_KEY,
        "AWS_SECRET_ACCESS_KEY": SECRET_KEY,
        "AWS_REGION": "us-east-1",
    }


class MotoS3:
    """An S3 endpoint at ``127.0.0.1:port``, with helpers to fill it."""

    def __init__(self, port: int) -> None:
        self.port = port
        self.endpoint = f"http://127.0.0.1:{port}"
        self.client = boto3.client(
            "s3",
            endpoint_url=self.endpoint,
            region_name="us-east-1",
            aws_access_key_id=ACCESS_KEY,
            aws_secret_access_key=SECRET_KEY,
        )

    def bucket(self, name: str) -> str:
        """Create bucket ``name`` (if needed); its name."""
        with contextlib.suppress(self.client.exceptions.BucketAlreadyOwnedByYou):
            self.client.create_bucket(Bucket=name)
        return name

    def upload(self, directory: Path, bucket: str, prefix: str) -> list[str]:
        """Put every file of ``directory`` (following links, recursively) under ``prefix``; the keys."""
        keys = []
        for path in sorted(Path(directory).rglob("*")):
            if path.is_file():
                key = f"{prefix}/{path.relative_to(directory).as_posix()}"
                self.client.put_object(Bucket=bucket, Key=key, Body=path.read_bytes())
                keys.append(key)
        return keys

    def put(self, bucket: str, key: str, data: bytes) -> None:
        self.client.put_object(Bucket=bucket, Key=key, Body=data)

    def delete(self, bucket: str, key: str) -> None:
        self.client.delete_object(Bucket=bucket, Key=key)


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


@contextlib.contextmanager
def moto_process() -> Iterator[MotoS3]:
    """moto's server in a process of its own (``moto_server``), stopped on exit."""
    port = free_port()
    process = subprocess.Popen(
        [sys.executable, "-m", "moto.server", "-H", "127.0.0.1", "-p", str(port)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env={**os.environ, "MOTO_PORT": str(port)},
    )
    try:
        deadline = time.monotonic() + 30
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                if process.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError("moto_server did not start") from None
                time.sleep(0.1)
        yield MotoS3(port)
    finally:
        process.terminate()
        try:
            process.wait(10)
        except subprocess.TimeoutExpired:  # a loaded machine: moto holding many keys may take longer to stop
            process.kill()
            process.wait()


@contextlib.asynccontextmanager
async def proxied(store: MotoS3, monkeypatch: pytest.MonkeyPatch, delay: float = 0.0) -> AsyncIterator[Proxy]:
    """A proxy (devkit/tcpproxy.py) to ``store``, waiting ``delay`` s before each request, and the AWS variables pointing
    at it for the test."""
    async with running_proxy(store.port, delay) as running:
        for name, value in store_env(running.url).items():
            monkeypatch.setenv(name, value)
        yield running
