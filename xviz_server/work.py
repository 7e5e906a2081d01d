"""Where blocking work runs, so that the event loop only schedules.

File reads and light work (decoding a GLB frame is a fraction of a
millisecond) run in a thread pool. Work that holds the GIL for long, such as
parsing or writing a JSON point cloud, runs in a process pool, created on
first use.
"""

from __future__ import annotations

import asyncio
import multiprocessing
import os
from concurrent.futures import Executor, ProcessPoolExecutor, ThreadPoolExecutor
from typing import Any, Callable, TypeVar

__all__ = ["Workers"]

T = TypeVar("T")


class Workers:
    """A thread pool for I/O and a lazily started process pool for CPU-heavy work."""

    def __init__(self, *, threads: int = 8, processes: int | None = None) -> None:
        self._threads = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="xviz-io")
        self._processes: Executor | None = None
        self._process_count = processes or os.cpu_count() or 1

    async def io(self, function: Callable[..., T], *args: Any) -> T:
        """Run ``function(*args)`` in the thread pool."""
        return await asyncio.get_running_loop().run_in_executor(self._threads, function, *args)

    async def cpu(self, function: Callable[..., T], *args: Any) -> T:
        """Run ``function(*args)`` in the process pool; it must be picklable."""
        return await asyncio.get_running_loop().run_in_executor(self._pool(), function, *args)

    async def warm(self) -> None:
        """Start the worker processes now, so that the first heavy job does not wait for them."""
        loop = asyncio.get_running_loop()
        pool = self._pool()
        await asyncio.gather(*(loop.run_in_executor(pool, _ready) for _ in range(self._process_count)))

    def _pool(self) -> Executor:
        if self._processes is None:
            methods = multiprocessing.get_all_start_methods()
            context = multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")
            self._processes = ProcessPoolExecutor(max_workers=self._process_count, mp_context=context)
        return self._processes

    def close(self) -> None:
        """Stop both pools; running jobs finish, queued ones are dropped."""
        self._threads.shutdown(wait=False, cancel_futures=True)
        if self._processes is not None:
            self._processes.shutdown(wait=False, cancel_futures=True)


def _ready() -> None:
    """Import what converters use, so that a worker's first real job does not pay for it."""
    import xviz_server.builder  # noqa: F401
    import xviz_server.datasets  # noqa: F401
