"""Where blocking work runs: threads for I/O, processes for heavy work once they are up."""

from __future__ import annotations

import asyncio
import os
import threading
from pathlib import Path

import pytest

import xviz_server
from xviz_server import frames
from xviz_server.codec import Format
from xviz_server.work import Place, Workers, _fork_server_finds_this_package


def test_heavy_work_runs_in_threads_until_the_worker_processes_are_up():
    async def main() -> tuple[int, int, int]:
        workers = Workers(processes=1)
        try:
            first = await workers.cpu(os.getpid)  # the pool has just been asked to start
            await workers.warm()
            later = await workers.cpu(os.getpid)
            io = await workers.io(os.getpid)
            return first, later, io
        finally:
            workers.close()

    first, later, io = asyncio.run(main())
    assert first == io == os.getpid()  # threads of this process
    assert later != os.getpid()


def where() -> tuple[int, int]:
    """The process and thread a job runs in."""
    return os.getpid(), threading.get_ident()


def test_a_job_runs_where_its_place_says():
    async def main() -> dict[Place, tuple[int, int]]:
        workers = Workers(processes=1)
        try:
            await workers.warm()
            return {place: await workers.run(place, where) for place in Place}
        finally:
            workers.close()

    here = (os.getpid(), threading.get_ident())
    seen = asyncio.run(main())
    assert seen[Place.LOOP] == here
    assert seen[Place.THREAD][0] == here[0] and seen[Place.THREAD][1] != here[1]
    assert seen[Place.PROCESS][0] != here[0]


def test_frames_run_in_the_loop_when_small_and_in_a_process_only_when_large_json():
    small, middle, large = frames.INLINE_BYTES, frames.INLINE_BYTES + 1, frames.HEAVY_JSON_BYTES + 1
    assert frames.placement(small, Format.JSON) is Place.LOOP
    assert frames.placement(middle, Format.JSON) is Place.THREAD
    assert frames.placement(frames.HEAVY_JSON_BYTES, Format.BINARY, Format.JSON) is Place.THREAD
    assert frames.placement(large, Format.BINARY) is Place.THREAD
    assert frames.placement(large, Format.BINARY, Format.JSON) is Place.PROCESS


def test_the_fork_server_preloads_only_where_the_working_directory_holds_no_other_copy(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    # It imports with the working directory first on sys.path (see work.py): another xviz_server/ there would win.
    monkeypatch.chdir(tmp_path)
    assert _fork_server_finds_this_package()
    monkeypatch.chdir(Path(xviz_server.__file__).parents[1])  # where this package's own folder is
    assert _fork_server_finds_this_package()
    (tmp_path / "xviz_server").mkdir()
    (tmp_path / "xviz_server" / "__init__.py").write_text("")
    monkeypatch.chdir(tmp_path)
    assert not _fork_server_finds_this_package()
