"""Reading a log's files from disk: small files from the page cache in the event loop, the rest in threads."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import pytest

from helpers import client, running_server, ten_hz, update, write_log
from xviz_server.codec import Format
from xviz_server.folders import _read_if_cached
from xviz_server.frames import INLINE_BYTES


def evict(directory: Path) -> None:
    """Drop the files of ``directory`` from the page cache (they are written out first)."""
    for path in directory.iterdir():
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
            os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
        finally:
            os.close(fd)


async def streamed(server, name: str) -> list[dict]:
    async with client(server, f"/{name}") as viewer:
        await viewer.recv()  # metadata
        await viewer.send("transform_log", {"id": "all"})
        return [m["data"] for m in await viewer.until("transform_log_done", "all") if m["type"] == "xviz/state_update"]


async def test_small_and_large_frames_are_served_from_the_page_cache_or_not(tmp_path: Path):
    updates = ten_hz(6)
    updates[3] = update(100.3, points=2000)  # a frame above INLINE_BYTES
    log = write_log(tmp_path / "logs" / "mixed", updates, fmt=Format.JSON)
    assert (log / "5-frame.json").stat().st_size > INLINE_BYTES > (log / "2-frame.json").stat().st_size

    evict(log)
    assert _read_if_cached(str(log / "2-frame.json")) == (None, True)  # not in the cache: never waits for the disk
    async with running_server(tmp_path / "logs") as server:
        cold = await streamed(server, "mixed")
    async with running_server(tmp_path / "logs") as server:
        assert _read_if_cached(str(log / "2-frame.json")) == ((log / "2-frame.json").read_bytes(), True)
        warm = await streamed(server, "mixed")
    assert len(cold) == 6 and warm == cold
    assert [u["updates"][0]["timestamp"] for u in cold] == [u["updates"][0]["timestamp"] for u in updates]
    assert len(cold[3]["updates"][0]["primitives"]["/points"]["points"][0]["points"]) == 2000


@pytest.mark.skipif(not os.path.isdir("/dev/shm"), reason="no tmpfs at /dev/shm")
async def test_a_log_on_a_file_system_that_cannot_read_without_waiting_is_served():
    # tmpfs refuses RWF_NOWAIT reads (EOPNOTSUPP) on the kernels this runs on, as NFS and FUSE do.
    scratch = Path(tempfile.mkdtemp(dir="/dev/shm"))
    try:
        write_log(scratch / "shm", ten_hz(4), fmt=Format.JSON)
        async with running_server(scratch) as server:
            first, again = await streamed(server, "shm"), await streamed(server, "shm")
        assert [u["updates"][0]["timestamp"] for u in first] == [100.0, 100.1, 100.2, 100.3] and again == first
    finally:
        shutil.rmtree(scratch)


async def test_a_fifo_in_place_of_a_frame_is_an_error_and_holds_nothing(tmp_path: Path):
    log = write_log(tmp_path / "logs" / "piped", ten_hz(4), fmt=Format.JSON)
    # preload_mb=0: a read-in started by the first session would race the swap and serve the frames from the cache.
    async with running_server(tmp_path / "logs", preload_mb=0) as server:
        async with client(server, "/piped") as viewer:
            await viewer.recv()  # metadata: the log is listed, no frame read yet
        listed = log.stat()
        for name in ("3-frame.json", "4-frame.json"):
            (log / name).unlink()
            os.mkfifo(log / name)
        os.utime(log, ns=(listed.st_atime_ns, listed.st_mtime_ns))  # the directory looks unchanged: no new listing
        async with client(server, "/piped") as viewer:
            await viewer.recv()  # metadata
            await viewer.send("transform_log", {"id": "all"})
            got = await viewer.until("transform_log_done", "all", timeout=10)
    errors = [m["data"]["message"] for m in got if m["type"] == "xviz/error"]
    assert [m["data"]["updates"][0]["timestamp"] for m in got if m["type"] == "xviz/state_update"] == [100.0, 100.3]
    assert len(errors) == 2 and all("not a regular file" in e for e in errors)
