"""A thread pool, one per process, for the parts of a frame's conversion that run without the GIL.

Pillow decoding, resizing and encoding images, and zlib inflating a
stream, release the GIL: submitted here, the parts of one frame are done
side by side, and beside what the caller does meanwhile (numpy work on point
clouds, which mostly releases it too). The threads, one per CPU, start on
first use in the process that uses them; a process forked from one that
has them starts without (the threads of its parent do not run in it), and
makes its own.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, TypeVar

__all__ = ["submit"]

T = TypeVar("T")

_pool: ThreadPoolExecutor | None = None
_lock = threading.Lock()


def _forget() -> None:
    global _pool, _lock
    _pool, _lock = None, threading.Lock()


os.register_at_fork(after_in_child=_forget)


def submit(function: Callable[..., T], *args: Any) -> Future[T]:
    """Start ``function(*args)`` in the pool; its future."""
    global _pool
    with _lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(max_workers=os.cpu_count() or 1, thread_name_prefix="xviz-frame")
    return _pool.submit(function, *args)
