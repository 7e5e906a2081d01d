"""``xviz-server inspect``: what a bag holds and what the mapping makes of it, to write a configuration from.

Everything comes from the bag's index except each topic's first message,
read to compare its header stamp with its record time: topics stamped on
another clock (simulation time beside wall time) are pointed out. Frames,
staleness and interpolation use record times, so such topics are served
like the others.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ...exceptions import DatasetError
from .dataset import RosBag
from .wellknown import nanoseconds

__all__ = ["inspect_bag", "render"]

#: Header stamps further than this from the record time are called another clock, seconds.
OTHER_CLOCK = 60.0


def _stamp_note(bag: RosBag, topic: str, first: int) -> str:
    try:
        _, message = bag.bag.message(topic, 0)
    except DatasetError as exc:
        return f"does not decode: {exc}"
    header = getattr(message, "header", None)
    if header is None:
        return ""
    stamp = nanoseconds(header.stamp) / 1e9
    offset = stamp - first / 1e9
    return f"header stamps on another clock ({offset:+.1f} s from record time)" if abs(offset) > OTHER_CLOCK else ""


def inspect_bag(path: Path, config: str | None = None) -> dict[str, Any]:
    """The report on the bag at ``path`` (with the configuration ``config``), as plain data."""
    dataset = RosBag(path, config=config)
    mappings = {m.topic: m for m in dataset.mappings}
    topics = []
    for name, info in dataset.bag.topics.items():
        count = len(info)
        first, last = (float(info.times[0]) / 1e9, float(info.times[-1]) / 1e9) if count else (None, None)
        rate = (count - 1) / (last - first) if count > 1 and last and first and last > first else None
        topics.append(
            {
                "topic": name,
                "type": info.msgtype,
                "count": count,
                "rate_hz": rate,
                "first": first,
                "last": last,
                "maps_to": mappings[name].describe(),
                "note": dataset.bag.problems.get(name)
                or (_stamp_note(dataset, name, int(info.times[0])) if count else "no message"),
            }
        )
    clock = dataset.settings.clock or next(
        (
            m.topic
            for m in dataset.mappings
            if m.role == "points" and len(dataset.bag.topics[m.topic]) and dataset.settings.rate is None
        ),
        None,
    )
    return {
        "path": str(dataset.path),
        "name": dataset.name,
        "container": dataset.bag.container,
        "start_time": float(dataset.times[0]),
        "end_time": float(dataset.times[-1]),
        "frames": len(dataset),
        "clock": f"one frame per message of {clock}" if clock else f"{dataset.settings.rate or 10.0:g} Hz",
        "pose": dataset.pose_source.describe(),
        "vehicle_frame": dataset.pose_source.vehicle_frame,
        "topics": topics,
    }


def render(report: dict[str, Any]) -> str:
    """The report as a table for a terminal."""
    start = min((t["first"] for t in report["topics"] if t["first"] is not None), default=0.0)
    rows = [("topic", "type", "count", "rate Hz", "span s", "maps to", "note")]
    for t in report["topics"]:
        span = "" if t["first"] is None else f"{t['first'] - start:.2f}..{t['last'] - start:.2f}"
        rate = "" if t["rate_hz"] is None else f"{t['rate_hz']:.2f}"
        rows.append((t["topic"], t["type"].replace("/msg/", "/"), str(t["count"]), rate, span, t["maps_to"], t["note"]))
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    lines = [
        f"{report['path']}: {report['container']} bag, {report['frames']} frames "
        f"({report['clock']}), {report['end_time'] - report['start_time']:.2f} s from {report['start_time']:.3f}",
        f"pose: {report['pose']}; vehicle frame: {report['vehicle_frame']}",
        "",
    ]
    lines += ["  ".join(cell.ljust(width) for cell, width in zip(row, widths)).rstrip() for row in rows]
    return "\n".join(lines)
