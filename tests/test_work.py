"""Where blocking work runs: threads for I/O, processes for heavy work once they are up."""

from __future__ import annotations

import asyncio
import os

from xviz_server.work import Workers


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
