"""A first layout for Lichtblick (and Foxglove) made from a log's channels: the 3D view, a camera and a plot.

Lichtblick takes no layout from its URL: a web app serves its default
layout inside its ``index.html`` (its Docker image puts the file
``/lichtblick/default-layout.json`` there on start), and both apps import a
layout file (*Layouts*, *Import from file*). :func:`app_layout` makes that
file for one log, in Lichtblick's layout format (``configById`` of panels
and the ``layout`` tree that places them): a 3D panel that follows the
vehicle's frame with the point clouds, scene updates and the vehicle's pose
shown; an Image panel of the first camera; a Plot of the first numeric time
series. The server answers it at ``GET /api/logs/NAME/layout.json``.
"""

from __future__ import annotations

from typing import Any

from .export import log_path
from .translate import ROOT_FRAME, Plan

__all__ = ["app_layout", "layout_path", "LAYOUT_SUFFIX"]

#: What a log's layout URL ends with, after ``/api/logs/NAME``.
LAYOUT_SUFFIX = "/layout.json"

#: The panels' ids: the panel's type, ``!``, a name of ours.
_THREE_D, _IMAGE, _PLOT = "3D!xviz", "Image!xviz", "Plot!xviz"


def layout_path(path: str) -> str | None:
    """The log a layout URL path (``/api/logs/NAME/layout.json``, percent-decoded) names, or ``None``."""
    return log_path(path, LAYOUT_SUFFIX)


def app_layout(plan: Plan) -> dict[str, Any]:
    """Lichtblick's layout data for a log of these channels (JSON-ready)."""
    by_kind: dict[str, list[str]] = {}
    for channel in plan.channels:
        by_kind.setdefault(channel.kind, []).append(channel.topic)
    shown = [*by_kind.get("points", ()), *by_kind.get("scene", ()), *by_kind.get("pose", ())]
    # The vehicle's frame: the one its clouds are drawn in (a pose stream's name), else the root.
    frames = [plan.frames[channel.stream][0] for channel in plan.channels if channel.kind == "points"]
    follow = next((frame for frame in frames if frame != ROOT_FRAME), ROOT_FRAME)
    config: dict[str, Any] = {
        _THREE_D: {
            "followTf": follow,
            "followMode": "follow-position",
            "topics": {topic: {"visible": True} for topic in shown},
            "scene": {"transforms": {"showLabel": False}},
        },
    }
    places: list[str] = [_THREE_D]
    images = by_kind.get("image", [])
    if images:
        config[_IMAGE] = {"imageMode": {"imageTopic": images[0]}}
        places.append(_IMAGE)
    numbers = [
        c.topic for c in plan.channels if c.kind == "time_series" and plan.values.get(c.stream) in ("number", "integer")
    ]
    if numbers:
        config[_PLOT] = {
            "paths": [{"value": f"{numbers[0]}.value", "enabled": True, "timestampMethod": "receiveTime"}],
            "showLegend": True,
            "legendDisplay": "floating",
            "showXAxisLabels": True,
            "showYAxisLabels": True,
            "isSynced": True,
            "xAxisVal": "timestamp",
        }
        places.append(_PLOT)
    return {
        "configById": config,
        "globalVariables": {},
        "userNodes": {},
        "playbackConfig": {"speed": 1.0},
        "layout": _split(places),
    }


def _split(places: list[str]) -> Any:
    """The mosaic tree: the 3D view on the left (70 %), the other panels stacked on the right."""
    if len(places) == 1:
        return places[0]
    right: Any = places[-1]
    for place in reversed(places[1:-1]):
        right = {"first": place, "second": right, "direction": "column", "splitPercentage": 50}
    return {"first": places[0], "second": right, "direction": "row", "splitPercentage": 70}
