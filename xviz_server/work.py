"""Where blocking work runs, so that the event loop only schedules.

File reads and light work (decoding a GLB frame is a fraction of a
millisecond) run in a thread pool. Work that holds the GIL for long, such as
parsing or writing a JSON point cloud, runs in a process pool, started on
first use. Starting it takes a few hundred milliseconds (the fork server
imports numpy and this package once, then forks the workers), so it starts
from a thread, and until it is up such work runs in a single thread rather
than wait: a single one, because the GIL lets no two of these jobs run at
once, and there the first job asked for is the first done.
"""

from __future__ import annotations

import asyncio
import multiprocessing
import os
import threading
from concurrent.futures import Executor, Future, ProcessPoolExecutor, ThreadPoolExecutor
from multiprocessing.context import BaseContext
from typing import Any, Callable, TypeVar

__all__ = ["Workers"]

T = TypeVar("T")

# What jobs sent to the process pool use: imported once by the fork server
# (or by each worker, where there is no fork server).
_JOB_MODULES = ["xviz_server.frames", "xviz_server.live", "xviz_server.builder", "xviz_server.datasets"]


class Workers:
    """A thread pool for I/O and a lazily started process pool for CPU-heavy work."""

    def __init__(self, *, threads: int = 8, processes: int | None = None) -> None:
        self._threads = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="xviz-io")
        self._stand_in = ThreadPoolExecutor(max_workers=1, thread_name_prefix="xviz-cpu")
        self._processes: ProcessPoolExecutor | None = None
        self._process_count = processes or os.cpu_count() or 1
        self._started: Future[None] | None = None  # done when every worker process is up
        self._lock = threading.Lock()
        self._closed = False

    async def io(self, function: Callable[..., T], *args: Any) -> T:
        """Run ``function(*args)`` in the thread pool."""
        return await asyncio.get_running_loop().run_in_executor(self._threads, function, *args)

    async def cpu(self, function: Callable[..., T], *args: Any) -> T:
        """Run ``function(*args)`` in the process pool; it must be picklable.

        While the pool is starting, it runs in a thread of this process.
        """
        started = self._start()
        executor: Executor | None = self._stand_in
        if started.done():
            started.result()  # raises if the pool could not start
            executor = self._processes
        return await asyncio.get_running_loop().run_in_executor(executor, function, *args)

    async def warm(self) -> None:
        """Start the worker processes now and wait until they are up."""
        await asyncio.wrap_future(self._start())

    def _start(self) -> Future[None]:
        if self._started is None:
            self._started = self._threads.submit(self._start_processes)
        return self._started

    def _start_processes(self) -> None:
        context: BaseContext
        if "forkserver" in multiprocessing.get_all_start_methods():
            context = multiprocessing.get_context("forkserver")
            context.set_forkserver_preload(_JOB_MODULES)
        else:
            context = multiprocessing.get_context("spawn")
        with self._lock:
            if self._closed:
                return
            self._processes = ProcessPoolExecutor(max_workers=self._process_count, mp_context=context)
        # The pool starts a process per job submitted while none is idle.
        for job in [self._processes.submit(_import_job_modules) for _ in range(self._process_count)]:
            job.result()

    def close(self) -> None:
        """Stop the pools; running jobs finish, queued ones are dropped."""
        with self._lock:
            self._closed = True
        self._threads.shutdown(wait=False, cancel_futures=True)
        self._stand_in.shutdown(wait=False, cancel_futures=True)
        if self._processes is not None:
            self._processes.shutdown(wait=False, cancel_futures=True)


def _import_job_modules() -> None:
    for name in _JOB_MODULES:
        __import__(name)
