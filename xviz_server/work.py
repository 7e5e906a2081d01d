"""Where blocking work runs, so that the event loop only schedules.

Jobs on a few kilobytes run in the event loop itself: they hold it for
less time than handing them to a thread takes. File reads and light work
(decoding a GLB frame is a fraction of a millisecond) run in a thread pool. Work that holds the GIL for long, such as
parsing or writing a JSON point cloud, runs in a process pool, started on
first use. Starting it takes a few hundred milliseconds (the fork server
imports numpy and this package once, then forks the workers), so it starts
from a thread, and until it is up such work runs in a single thread rather
than wait: a single one, because the GIL lets no two of these jobs run at
once, and there the first job asked for is the first done.

A worker process that dies (killed, out of memory) breaks the whole process
pool: every job in it fails with ``BrokenProcessPool``. The pool is then
replaced, the same way it was first started, and the job is tried once more;
:meth:`Workers.health` tells a pool that is broken and not yet replaced.
"""

from __future__ import annotations

import asyncio
import ctypes
import enum
import importlib.machinery
import logging
import multiprocessing
import os
import sys
import threading
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor, ThreadPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from multiprocessing.context import BaseContext
from typing import Any, TypeVar

from .exceptions import WorkerError

__all__ = ["Place", "Workers"]

T = TypeVar("T")

logger = logging.getLogger(__name__)

# What jobs sent to the process pool use: imported once by the fork server
# (or by each worker, where there is no fork server).
_JOB_MODULES = [
    "xviz_server.frames",
    "xviz_server.admission",
    "xviz_server.live",
    "xviz_server.builder",
    "xviz_server.datasets",
]


class Place(enum.Enum):
    """Where a job runs (see :meth:`Workers.run`)."""

    LOOP = "loop"  #: in the calling coroutine, holding the event loop
    THREAD = "thread"  #: in the thread pool
    PROCESS = "process"  #: in the process pool


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

    async def run(self, place: Place, function: Callable[..., T], *args: Any) -> T:
        """Run ``function(*args)`` where ``place`` says."""
        if place is Place.LOOP:
            return function(*args)
        if place is Place.THREAD:
            return await self.io(function, *args)
        return await self.cpu(function, *args)

    async def io(self, function: Callable[..., T], *args: Any) -> T:
        """Run ``function(*args)`` in the thread pool."""
        return await asyncio.get_running_loop().run_in_executor(self._threads, function, *args)

    async def cpu(self, function: Callable[..., T], *args: Any, isolated: bool = False) -> T:
        """Run ``function(*args)`` in the process pool; it must be picklable.

        While the pool is starting, it runs in a thread of this process,
        unless ``isolated``: then it waits for the pool (a job on untrusted
        bytes, such as opening a recording, never runs in this process). When
        a worker process dies, the pool is replaced and the job tried once
        more; raises :class:`~xviz_server.exceptions.WorkerError` when it dies
        again.
        """
        loop = asyncio.get_running_loop()
        for _attempt in range(2):
            started = self._start()
            if isolated:
                await asyncio.wrap_future(started)
            elif not started.done():
                return await loop.run_in_executor(self._stand_in, function, *args)
            started.result()  # raises if the pool could not start
            pool = self._processes
            try:
                return await loop.run_in_executor(pool, function, *args)
            except BrokenProcessPool:
                logger.warning("a worker process died running %s; replacing the process pool", _name(function))
                self._replace(pool)
        raise WorkerError(
            f"a worker process died running {_name(function)}, in the process pool and in its replacement"
        )

    def health(self) -> list[str]:
        """What is wrong with the workers now, one sentence each; empty when nothing is.

        A broken process pool found here is replaced (the next job would
        replace it too).
        """
        started, pool = self._started, self._processes
        if started is None or not started.done():
            return []
        if started.exception() is not None:
            return [f"the worker processes could not start: {started.exception()}"]
        if pool is None:
            return []
        try:  # submit() is where a pool tells that it is broken
            pool.submit(_nothing)
        except BrokenProcessPool:
            self._replace(pool)
            return ["a worker process died: the process pool is broken, and being replaced"]
        except RuntimeError:  # shut down: the server is closing
            return ["the worker processes are shut down"]
        return []

    async def warm(self) -> None:
        """Start the worker processes now and wait until they are up."""
        await asyncio.wrap_future(self._start())

    def _start(self) -> Future[None]:
        if self._started is None:
            self._started = self._threads.submit(self._start_processes)
        return self._started

    def _replace(self, broken: ProcessPoolExecutor | None) -> None:
        """Start a new process pool in place of ``broken``, unless that was done already."""
        with self._lock:
            if self._processes is not broken or self._closed:
                return
            self._processes = None
            self._started = None
        if broken is not None:
            broken.shutdown(wait=False, cancel_futures=True)
        self._start()

    def _start_processes(self) -> None:
        context: BaseContext
        if "forkserver" in multiprocessing.get_all_start_methods():
            context = multiprocessing.get_context("forkserver")
            context.set_forkserver_preload(_JOB_MODULES if _fork_server_finds_this_package() else [])
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


def _name(function: Callable[..., Any]) -> str:
    return getattr(function, "__qualname__", repr(function))


def _nothing() -> None:
    pass


def _fork_server_finds_this_package() -> bool:
    """Whether the fork server's imports would find this package, not another copy of it.

    The fork server is started as ``python -c``, so it imports with the
    working directory first on ``sys.path``; Python before 3.12.8 and 3.13.1
    does not give it the parent's ``sys.path`` (CPython issue gh-117378).
    Where the working directory holds another copy of the package (an
    installed server started at the root of a checkout, whose ``xviz_server/``
    lacks the subpackages mapped in from ``providers/`` and ``schema/``), a
    preloading fork server would hand that copy to every worker. Then it
    preloads nothing, and each worker imports the job modules itself, with the
    parent's ``sys.path``: a slower start, the same jobs.
    """
    package = __name__.rpartition(".")[0]
    found = importlib.machinery.PathFinder.find_spec(package, [os.getcwd()])
    if found is None or found.origin is None:
        return True
    ours = sys.modules[package].__file__
    return ours is not None and os.path.exists(found.origin) and os.path.samefile(found.origin, ours)


def _import_job_modules() -> None:
    for name in _JOB_MODULES:
        __import__(name)
    _keep_freed_memory()


# glibc's mallopt() parameters
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3


def _keep_freed_memory() -> None:
    """Let this worker reuse the memory its jobs free, rather than map fresh pages for each array.

    Frame jobs allocate and free arrays of a few megabytes; glibc maps each
    anew (and faults every page in) above its mapping threshold. Up to
    32 MB an array comes from the heap, and up to 64 MB of freed heap is
    kept. Nothing is done where the C library has no ``mallopt``.
    """
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (AttributeError, OSError):
        return
    mallopt(_M_MMAP_THRESHOLD, 32 << 20)
    mallopt(_M_TRIM_THRESHOLD, 64 << 20)
