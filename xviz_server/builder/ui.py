"""Declarative UI: panels of components that streetscape.gl lays out from the metadata.

Each function returns the plain dict the specification describes (the
published schema wants a ``title`` on every component but a video); give a
:func:`panel` to :meth:`~xviz_server.builder.MetadataBuilder.ui_panel`,
which checks it against the schema and, at ``build()``, checks that the
streams it shows are declared::

    meta.ui_panel(ui.panel(
        "Vehicle",
        ui.container("Motion", ui.metric(["/vehicle/velocity"], title="Velocity"),
                     ui.plot("/plan/distance", ["/plan/speed"], title="Speed plan")),
        ui.table("/objects/table", title="Objects"),
        ui.video(["/camera/front"]),
    ))
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

__all__ = ["panel", "container", "metric", "plot", "table", "treetable", "video", "select"]


def _component(kind: str, title: str | None, description: str | None, **fields: Any) -> dict[str, Any]:
    component: dict[str, Any] = {"type": kind}
    if title is not None:
        component["title"] = title
    if description is not None:
        component["description"] = description
    component.update({key: value for key, value in fields.items() if value is not None})
    return component


def panel(name: str, *children: dict[str, Any], layout: str = "VERTICAL") -> dict[str, Any]:
    """A panel (usually shown as a tab) of components and containers, laid out ``VERTICAL`` or ``HORIZONTAL``."""
    return {"type": "PANEL", "name": name, "layout": layout, "children": list(children)}


def container(name: str, *children: dict[str, Any], layout: str = "HORIZONTAL") -> dict[str, Any]:
    """Components (and containers) laid out together inside a panel."""
    return {"type": "CONTAINER", "name": name, "layout": layout, "children": list(children)}


def metric(streams: Sequence[str], *, title: str, description: str | None = None) -> dict[str, Any]:
    """A chart of time series streams over time."""
    return _component("METRIC", title, description, streams=list(streams))


def plot(
    independent: str | None = None,
    dependents: Sequence[str] = (),
    *,
    regions: Sequence[tuple[str, str, str]] | None = None,
    title: str,
    description: str | None = None,
) -> dict[str, Any]:
    """Variable streams plotted against another (a speed plan against distance), and/or
    ``regions``: (x, y_min, y_max) variable streams bounding a shaded area."""
    return _component(
        "PLOT",
        title,
        description,
        independentVariable=independent,
        dependentVariables=list(dependents) if dependents else None,
        regions=[{"x": x, "yMin": low, "yMax": high} for x, low, high in regions] if regions else None,
    )


def table(
    stream: str, *, title: str, description: str | None = None, display_object_id: bool | None = None
) -> dict[str, Any]:
    """A flat table of a treetable UI-primitive stream."""
    return _component("TABLE", title, description, stream=stream, displayObjectId=display_object_id)


def treetable(
    stream: str, *, title: str, description: str | None = None, display_object_id: bool | None = None
) -> dict[str, Any]:
    """A collapsible tree table of a treetable UI-primitive stream."""
    return _component("TREETABLE", title, description, stream=stream, displayObjectId=display_object_id)


def video(cameras: Sequence[str], *, title: str | None = None, description: str | None = None) -> dict[str, Any]:
    """Video of image streams (or cameras of the metadata), one at a time, chosen by the user."""
    return _component("VIDEO", title, description, cameras=list(cameras))


def select(stream: str, target: str, *, title: str, description: str | None = None) -> dict[str, Any]:
    """A drop-down of a stream's values; choosing one sets the configuration key ``target`` (a JSON pointer)."""
    return _component("SELECT", title, description, stream=stream, onchange={"target": target})
