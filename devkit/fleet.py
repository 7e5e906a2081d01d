"""Fleets of small logs in the reference layout, for the catalog's tests and benchmark.

A fleet cuts its drives into short segments, one log each: :func:`write_fleet`
writes such logs (an index document, JSON metadata, two frames), fast enough
for 100 000 of them when their frames are hard links.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

from xviz_server.codec import Format, encode
from xviz_server.layout import INDEX_FILE, file_number, index_document

__all__ = ["FLEET_START", "FleetLog", "write_fleet"]


@dataclass(frozen=True)
class FleetLog:
    """One log of :func:`write_fleet`: its name, time range, vehicle and description."""

    name: str
    start: float
    end: float
    vehicle: str
    description: str


#: When the first log of :func:`write_fleet` starts (UNIX seconds): 2020-09-13.
FLEET_START = 1_600_000_000.0


def write_fleet(
    root: Path, count: int, *, cars: int = 10, first: int = 0, frames_from: Path | None = None, index: bool = True
) -> list[FleetLog]:
    """``count`` small logs in the reference layout under ``root``, as a fleet cuts its drives: ``car-NN/seg-NNNNNN``.

    Log ``i`` starts a minute after log ``i - 1`` and lasts 10 to 59 s; its metadata's ``log_info`` gives its
    ``description`` ("segment i of car-NN, city|highway"), ``vehicle`` and ``tags``, and its streams are three
    of the four of :func:`metadata`'s kind (``/camera`` only on every third log). Each has an index document,
    JSON metadata and two JSON frames, written; with ``frames_from`` (a log made by an earlier call), its
    frames are hard links of that log's (the catalog reads no frame: a fleet of 100 000 costs less to make).
    Without ``index``, no log has an index document, as fleets are often written.
    """
    logs = []
    for i in range(first, first + count):
        car = f"car-{i % cars:02d}"
        start = FLEET_START + 60 * i
        end = start + 10 + i % 50
        road = "highway" if i % 4 == 0 else "city"
        name = f"{car}/seg-{i:06d}"
        description = f"segment {i} of {car}, {road}"
        streams = {
            "/vehicle_pose": {"category": "POSE"},
            "/points": {"category": "PRIMITIVE", "primitive_type": "POINT"},
        }
        if i % 3 == 0:
            streams["/camera"] = {"category": "PRIMITIVE", "primitive_type": "IMAGE"}
        meta = {
            "version": "2.0.0",
            "streams": streams,
            "log_info": {
                "start_time": start,
                "end_time": end,
                "description": description,
                "vehicle": car,
                "tags": [road],
            },
        }
        directory = root / name
        directory.mkdir(parents=True)
        (directory / "1-frame.json").write_bytes(encode({"type": "xviz/metadata", "data": meta}, Format.JSON))
        for frame, t in enumerate((start, end)):
            target = directory / f"{file_number(frame)}-frame.json"
            if frames_from is not None:
                os.link(frames_from / target.name, target)
            else:
                pose = {"timestamp": t, "position": [t, 0.0, 0.0], "orientation": [0.0, 0.0, 0.0]}
                data = {"update_type": "SNAPSHOT", "updates": [{"timestamp": t, "poses": {"/vehicle_pose": pose}}]}
                target.write_bytes(encode({"type": "xviz/state_update", "data": data}, Format.JSON))
        if index:
            (directory / INDEX_FILE).write_text(json.dumps(index_document([(start, start), (end, end)])))
        logs.append(FleetLog(name, start, end, car, description))
    return logs
