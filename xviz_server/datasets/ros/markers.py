"""``visualization_msgs`` markers and ``nav_msgs/Path`` drawn as XVIZ primitives.

Markers are stateful in ROS: one stays until a DELETE of its namespace and
id, a DELETEALL, or the end of its lifetime. A frame replays the marker
messages of the staleness window before it, in order, and draws what is
left; a marker older than the window is gone.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

import numpy as np

from ...builder import FrameBuilder
from ..shared import footprints
from .geometry import apply, from_pose
from .wellknown import nanoseconds

__all__ = ["live_markers", "draw_marker", "path_vertices"]

ARROW, CUBE, SPHERE, CYLINDER, LINE_STRIP, LINE_LIST, CUBE_LIST, SPHERE_LIST, POINTS, TEXT_VIEW_FACING = range(10)
DELETE, DELETEALL = 2, 3

#: Frame id to the transform into the vehicle frame, ``None`` when it cannot be resolved.
Resolver = Callable[[str], "np.ndarray | None"]


def live_markers(messages: Iterable[tuple[int, Any]], t: int) -> list[Any]:
    """The markers standing at ``t`` ns after replaying ``messages`` (``Marker`` or ``MarkerArray``, in time order)."""
    live: dict[tuple[str, int], tuple[int, Any]] = {}
    for time, message in messages:
        for marker in getattr(message, "markers", None) or [message]:
            if marker.action == DELETEALL:
                live = {key: value for key, value in live.items() if marker.ns and key[0] != marker.ns}
            elif marker.action == DELETE:
                live.pop((marker.ns, marker.id), None)
            else:
                live[(marker.ns, marker.id)] = (time, marker)
    standing = []
    for time, marker in live.values():
        lifetime = nanoseconds(marker.lifetime)
        if not lifetime or time + lifetime >= t:
            standing.append(marker)
    return standing


def _color(color: Any) -> list[int]:
    return [int(round(min(max(c, 0.0), 1.0) * 255)) for c in (color.r, color.g, color.b, color.a)]


def _points(points: Any) -> np.ndarray:
    return np.array([(p.x, p.y, p.z) for p in points], dtype=np.float64).reshape(-1, 3)


def _boxes(centers: np.ndarray, scale: Any) -> np.ndarray:
    """Footprints (bottom corners) of boxes of ``scale`` at ``centers`` (marker frame), (N, 4, 3)."""
    count = len(centers)
    bottoms = centers - np.array([0.0, 0.0, scale.z / 2])
    return footprints(bottoms, np.zeros(count), np.full(count, scale.x), np.full(count, scale.y))


def draw_marker(builder: FrameBuilder, stream: str, marker: Any, to_vehicle: np.ndarray) -> None:
    """Draw one marker into ``<stream>/polygons``, ``/polylines``, ``/points``, ``/circles`` or ``/texts``.

    ``to_vehicle`` takes the marker's frame into the vehicle frame. Types
    XVIZ has no primitive for (meshes, triangle lists) are skipped.
    """
    pose = to_vehicle @ from_pose(marker.pose)
    color = _color(marker.color)
    object_id = f"{marker.ns}/{marker.id}" if marker.ns else str(marker.id)
    scale = marker.scale
    local = _points(marker.points)
    kind = marker.type
    # One colour a point (lists and POINTS) when the marker gives as many as it has points, as RViz draws them.
    listed = kind in (CUBE_LIST, SPHERE_LIST, POINTS) and len(local) and len(marker.colors) == len(local)
    each = [_color(c) for c in marker.colors] if listed else None
    if kind in (CUBE, CUBE_LIST):
        centers = np.zeros((1, 3)) if kind == CUBE else local
        fills = each or [color] * len(centers)
        for corners, fill in zip(_boxes(centers, scale), fills):
            builder.polygon(
                f"{stream}/polygons",
                apply(pose, corners),
                id=object_id,
                style={"fill_color": fill, "height": float(scale.z)},
            )
    elif kind in (SPHERE, CYLINDER, SPHERE_LIST):
        centers = np.zeros((1, 3)) if kind != SPHERE_LIST else local
        fills = each or [color] * len(centers)
        for center, fill in zip(apply(pose, centers), fills):
            builder.circle(
                f"{stream}/circles", center.tolist(), float(scale.x) / 2, id=object_id, style={"fill_color": fill}
            )
    elif kind == ARROW:
        ends = local[:2] if len(local) >= 2 else np.array([[0.0, 0.0, 0.0], [scale.x, 0.0, 0.0]])
        builder.polyline(f"{stream}/polylines", apply(pose, ends), id=object_id, style={"stroke_color": color})
    elif kind == LINE_STRIP and len(local) >= 2:
        builder.polyline(f"{stream}/polylines", apply(pose, local), id=object_id, style={"stroke_color": color})
    elif kind == LINE_LIST:
        for pair in apply(pose, local[: len(local) // 2 * 2]).reshape(-1, 2, 3):
            builder.polyline(f"{stream}/polylines", pair, id=object_id, style={"stroke_color": color})
    elif kind == POINTS and len(local):
        colors = np.array(each, dtype=np.uint8) if each else None
        builder.points(f"{stream}/points", apply(pose, local), colors, id=object_id)
    elif kind == TEXT_VIEW_FACING:
        builder.text(f"{stream}/texts", pose[:3, 3].tolist(), marker.text, id=object_id, style={"fill_color": color})


def path_vertices(message: Any, resolve: Resolver) -> np.ndarray | None:
    """The positions of a ``nav_msgs/Path`` in the vehicle frame; ``None`` if its frame cannot be resolved."""
    to_vehicle = resolve(message.header.frame_id)
    if to_vehicle is None:
        return None
    positions = np.array([(p.pose.position.x, p.pose.position.y, p.pose.position.z) for p in message.poses]).reshape(
        -1, 3
    )
    return apply(to_vehicle, positions)
