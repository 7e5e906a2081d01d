"""Pure operations on state updates: stream filtering, complete-state merging, point thinning.

A state update's data holds ``updates``, a list of stream sets. A stream set
carries its streams in maps keyed by stream name (``poses``, ``primitives``,
``future_instances``, ``variables``, ``ui_primitives``, ``annotations``,
``links``), in ``time_series`` entries that each list several streams with
parallel value arrays, and in ``no_data_streams``. Nothing here copies
arrays: results share them with their inputs.
"""

from __future__ import annotations

from collections.abc import Collection, Iterable
from typing import Any

import numpy as np

__all__ = [
    "COMPLETE_TYPES",
    "update_streams",
    "filter_streams",
    "complete_state",
    "downsample_points",
    "shift_times",
]

STREAM_MAPS = ("poses", "primitives", "future_instances", "variables", "ui_primitives", "annotations", "links")
# Update types whose stream sets hold the whole state at their time.
COMPLETE_TYPES = frozenset({"COMPLETE_STATE", "SNAPSHOT"})
_VALUE_KINDS = ("doubles", "int32s", "bools", "strings")


def update_streams(data: dict[str, Any]) -> set[str]:
    """Every stream name carried by a state update's data."""
    names: set[str] = set()
    for stream_set in data.get("updates") or ():
        for key in STREAM_MAPS:
            names.update(stream_set.get(key) or ())
        for entry in stream_set.get("time_series") or ():
            names.update(entry.get("streams") or ())
        names.update(stream_set.get("no_data_streams") or ())
    return names


def _time_series_subset(entry: dict[str, Any], wanted: Collection[str]) -> dict[str, Any] | None:
    """The part of a time-series entry about ``wanted`` streams, or ``None``."""
    streams = entry.get("streams") or []
    keep = [i for i, name in enumerate(streams) if name in wanted]
    if len(keep) == len(streams):
        return entry
    if not keep:
        return None
    subset = dict(entry)
    subset["streams"] = [streams[i] for i in keep]
    values = entry.get("values") or {}
    subset["values"] = {
        kind: [array[i] for i in keep] if kind in _VALUE_KINDS and isinstance(array, list) else array
        for kind, array in values.items()
    }
    return subset


def _filter_stream_set(stream_set: dict[str, Any], wanted: Collection[str]) -> dict[str, Any]:
    result: dict[str, Any] = {}
    for key, value in stream_set.items():
        if key in STREAM_MAPS and isinstance(value, dict):
            kept = {name: state for name, state in value.items() if name in wanted}
            if kept:
                result[key] = kept
        elif key == "time_series" and isinstance(value, list):
            entries = [e for e in (_time_series_subset(entry, wanted) for entry in value) if e is not None]
            if entries:
                result[key] = entries
        elif key == "no_data_streams" and isinstance(value, list):
            kept_names = [name for name in value if name in wanted]
            if kept_names:
                result[key] = kept_names
        else:
            result[key] = value
    return result


def filter_streams(message: dict[str, Any], wanted: Collection[str]) -> dict[str, Any]:
    """A state-update envelope reduced to the ``wanted`` streams.

    Everything that is not a stream (timestamps, update type) is kept.
    """
    data = message["data"]
    updates = [_filter_stream_set(stream_set, wanted) for stream_set in data.get("updates") or ()]
    return {**message, "data": {**data, "updates": updates}}


def complete_state(
    messages: Iterable[dict[str, Any]], wanted: Collection[str] | None = None
) -> tuple[dict[str, Any], bool]:
    """Merge state updates, newest first, into one ``COMPLETE_STATE`` update.

    Each stream takes its state from the newest message that carries it.
    Merging stops after the first message whose update type is complete
    (``COMPLETE_STATE`` or the legacy ``SNAPSHOT``), since older messages
    cannot add to it. Returns the envelope and whether such a message was
    reached (if not, the caller may pass older messages for the streams
    still missing).

    The timestamp is that of the newest stream set.
    """
    merged: dict[str, Any] = {}
    taken: set[str] = set()
    series: list[dict[str, Any]] = []
    timestamp = None
    reached = False
    for message in messages:
        data = message.get("data") or {}
        for stream_set in reversed(data.get("updates") or []):
            if timestamp is None:
                timestamp = stream_set.get("timestamp")
            _merge_stream_set(stream_set, wanted, merged, taken, series)
        if str(data.get("update_type", "")).upper() in COMPLETE_TYPES:
            reached = True
            break
    update: dict[str, Any] = {"timestamp": timestamp, **merged}
    if series:
        update["time_series"] = series
    envelope = {"type": "xviz/state_update", "data": {"update_type": "COMPLETE_STATE", "updates": [update]}}
    return envelope, reached


def _merge_stream_set(
    stream_set: dict[str, Any],
    wanted: Collection[str] | None,
    merged: dict[str, Any],
    taken: set[str],
    series: list[dict[str, Any]],
) -> None:
    """Add the streams of ``stream_set`` that are wanted and not yet taken."""
    for key in STREAM_MAPS:
        for name, state in (stream_set.get(key) or {}).items():
            if name not in taken and (wanted is None or name in wanted):
                merged.setdefault(key, {})[name] = state
                taken.add(name)
    fresh = []
    for entry in stream_set.get("time_series") or ():
        names = {n for n in entry.get("streams") or () if n not in taken and (wanted is None or n in wanted)}
        subset = _time_series_subset(entry, names)
        if subset is not None:
            fresh.append(subset)
    for entry in fresh:
        taken.update(entry["streams"])
    series.extend(fresh)


def downsample_points(message: dict[str, Any], max_points: int) -> dict[str, Any]:
    """``message`` with every point cloud thinned to at most ``max_points`` points.

    Every k-th point is kept (with its colour), k the smallest stride that
    fits; arrays are sliced, not copied.
    """

    def thin(cloud: dict[str, Any]) -> dict[str, Any]:
        points = cloud.get("points")
        count = len(points) if points is not None else 0
        if count <= max_points or not isinstance(points, np.ndarray):
            return cloud
        stride = -(-count // max_points)
        result = {**cloud, "points": points[::stride]}
        colors = cloud.get("colors")
        if isinstance(colors, np.ndarray) and len(colors) == count:
            result["colors"] = colors[::stride]
        return result

    updates = []
    for stream_set in message["data"].get("updates") or ():
        primitives = {
            name: {**state, "points": [thin(cloud) for cloud in state["points"]]} if "points" in state else state
            for name, state in (stream_set.get("primitives") or {}).items()
        }
        updates.append({**stream_set, "primitives": primitives} if primitives else stream_set)
    return {**message, "data": {**message["data"], "updates": updates}}


def shift_times(message: dict[str, Any], seconds: float) -> dict[str, Any]:
    """A state-update envelope with every timestamp (stream sets, poses, time series) ``seconds`` later."""
    updates = []
    for stream_set in message["data"].get("updates") or ():
        shifted = {**stream_set, "timestamp": stream_set["timestamp"] + seconds}
        if "poses" in stream_set:
            shifted["poses"] = {
                name: {**pose, "timestamp": pose["timestamp"] + seconds} if "timestamp" in pose else pose
                for name, pose in stream_set["poses"].items()
            }
        if "time_series" in stream_set:
            shifted["time_series"] = [
                {**entry, "timestamp": entry["timestamp"] + seconds} if "timestamp" in entry else entry
                for entry in stream_set["time_series"]
            ]
        updates.append(shifted)
    return {**message, "data": {**message["data"], "updates": updates}}
