"""The benchmarks' kit: what every benchmark in ``scripts/bench/`` shares, and all it imports.

A benchmark imports this package (``scripts/bench/`` is the path of a script
run from it), :mod:`devkit` (the helpers it shares with the test suite) and
the product, never another benchmark. Here:

- :func:`percentile` and :func:`median_ms`, computed one way;
- :func:`parse`: every benchmark's command line, with ``--quick`` (a run of a
  few seconds that only shows it still works, what CI runs);
- the real data's paths, read once through ``XVIZ_SHARED_DIR`` (:mod:`devkit.data`);
- synthetic logs written by the product (:func:`metadata`, :func:`update`, :func:`write_log`);
- :mod:`kit.proc`: processes (the server, the reference server, Redis,
  client processes) and what they cost; :mod:`kit.peers` is the program of
  the reference server and the client processes;
- :mod:`kit.ws`: the one hand-written WebSocket client, and raw writes to viewers;
- :mod:`kit.gen`: generated data (ROS bags) and served-on-demand rates.
"""

from __future__ import annotations

import argparse
import gc
import math
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from devkit.data import KITTI_FRAME, KITTI_LOG, KITTI_RAW, SHARED_DIR
from xviz_server.builder import FrameBuilder, MetadataBuilder
from xviz_server.codec import Format
from xviz_server.writer import LogWriter

__all__ = [
    "REPO",
    "SHARED_DIR",
    "KITTI",
    "KITTI_RAW",
    "KITTI_FRAME",
    "percentile",
    "median_ms",
    "parse",
    "metadata",
    "update",
    "write_log",
]

#: The repository's root.
REPO = Path(__file__).resolve().parents[3]
#: The official 25-frame KITTI log.
KITTI = KITTI_LOG


def percentile(values: list[float] | np.ndarray, q: float) -> float:
    """The ``q``-th percentile by nearest rank (p99 of 500 values is the 5th largest); every benchmark uses this."""
    ordered = np.sort(np.asarray(values, dtype=np.float64))
    return float(ordered[max(0, math.ceil(q / 100 * len(ordered)) - 1)])


def median_ms(function: Callable[[], Any], repeat: int) -> float:
    """The median time of ``function`` over ``repeat`` calls after one to warm up, in ms, with the collector off."""
    function()  # warm up
    gc.disable()
    try:
        times = []
        for _ in range(repeat):
            start = time.perf_counter()
            function()
            times.append(time.perf_counter() - start)
    finally:
        gc.enable()
    return statistics.median(times) * 1000


def parse(parser: argparse.ArgumentParser, quick: dict[str, Any], argv: list[str] | None = None) -> argparse.Namespace:
    """Parse a benchmark's command line, which also takes ``--quick``: then ``quick``'s values replace the options'.

    ``quick`` names options by their destination (``{"runs": 1, "seconds": 1.0}``)
    and sizes the run to a few seconds; what it measures is then meaningless,
    but every code path runs and the tables are printed (CI runs each
    benchmark so: ``tests/test_benchmarks.py``).
    """
    parser.add_argument(
        "--quick", action="store_true", help="a run of a few seconds, to check that the benchmark works"
    )
    args = parser.parse_args(argv)
    if args.quick:
        for name, value in quick.items():
            assert hasattr(args, name), name
            setattr(args, name, value)
    return args


def metadata(start_time: float | None = None, end_time: float | None = None) -> dict[str, Any]:
    """The metadata of :func:`update`'s frames: a pose, a point cloud, a time series."""
    meta = MetadataBuilder().pose("/vehicle_pose").primitive("/points", "POINT").time_series("/speed", "FLOAT")
    if start_time is not None:
        meta.log_info(start_time=start_time, end_time=end_time)
    return meta.build()


def update(t: float, points: int = 10, meta: dict[str, Any] | None = None) -> dict[str, Any]:
    """A SNAPSHOT state update at time ``t``: the pose, ``points`` points, the speed."""
    frame = FrameBuilder(meta or metadata())
    frame.pose("/vehicle_pose", t, position=(t, 0.0, 0.0))
    frame.points("/points", np.full((points, 3), t, dtype=np.float32))
    frame.time_series("/speed", t, t * 2)
    return frame.build(t)


def write_log(
    directory: Path, count: int, *, points: int = 10, fmt: Format = Format.BINARY, start: float = 100.0
) -> Path:
    """A log of ``count`` frames at 10 Hz, written by the product's :class:`LogWriter`."""
    meta = metadata(start, start + (count - 1) / 10)
    with LogWriter(directory, fmt) as writer:
        writer.write_metadata(meta)
        for i in range(count):
            writer.write_frame(i, update(round(start + i / 10, 3), points, meta))
    return directory
