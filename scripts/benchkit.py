"""What the benchmarks share: percentiles computed one way, and synthetic logs written by the product.

Benchmarks import this (``scripts/`` is on the path of a script run from it),
never the test suite.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from xviz_server.builder import FrameBuilder, MetadataBuilder  # noqa: E402
from xviz_server.codec import Format  # noqa: E402
from xviz_server.writer import LogWriter  # noqa: E402

__all__ = ["percentile", "metadata", "update", "write_log"]


def percentile(values: list[float] | np.ndarray, q: float) -> float:
    """The ``q``-th percentile by nearest rank (p99 of 500 values is the 5th largest); every benchmark uses this."""
    ordered = np.sort(np.asarray(values, dtype=np.float64))
    return float(ordered[max(0, math.ceil(q / 100 * len(ordered)) - 1)])


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


def write_log(directory: Path, count: int, *, points: int = 10, fmt: Format = Format.BINARY, start: float = 100.0) -> Path:
    """A log of ``count`` frames at 10 Hz, written by the product's :class:`LogWriter`."""
    meta = metadata(start, start + (count - 1) / 10)
    with LogWriter(directory, fmt) as writer:
        writer.write_metadata(meta)
        for i in range(count):
            writer.write_frame(i, update(round(start + i / 10, 3), points, meta))
    return directory
