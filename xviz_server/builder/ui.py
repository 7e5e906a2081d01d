"""Declarative UI: panels of components that streetscape.gl lays out from the metadata.

Each function returns the plain dict the specification describes; pass a
:func:`panel` to :meth:`~xviz_server.builder.MetadataBuilder.ui_panel`.
"""

from __future__ import annotations

from typing import Any, Sequence

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
    """A panel (usually shown as a tab) holding components and containers."""
    return {"type": "PANEL", "name": name, "layout": layout, "children": list(children)}


def container(name: str, *children: dict[str, Any], layout: str = "HORIZONTAL") -> dict[str, Any]:
    """A group of components laid out together inside a panel."""
    return {"type": "CONTAINER", "name": name, "layout": layout, "children": list(children)}


def metric(streams: Sequence[str], *, title: str | None = None, description: str | None = None) -> dict[str, Any]:
    """A chart of time series or variable streams over time."""
    return _component("METRIC", title, description, streams=list(streams))


def plot(
    independent: str, dependents: Sequence[str], *, title: str | None = None, description: str | None = None
) -> dict[str, Any]:
    """Variables plotted against another variable (e.g. a speed plan against distance)."""
    return _component(
        "PLOT", title, description, independentVariable=independent, dependentVariables=list(dependents)
    )


def table(stream: str, *, title: str | None = None, description: str | None = None, display_object_id: bool | None = None) -> dict[str, Any]:
    """A flat table of a treetable UI-primitive stream."""
    return _component("TABLE", title, description, stream=stream, displayObjectId=display_object_id)


def treetable(stream: str, *, title: str | None = None, description: str | None = None, display_object_id: bool | None = None) -> dict[str, Any]:
    """A hierarchical table of a treetable UI-primitive stream."""
    return _component("TREETABLE", title, description, stream=stream, displayObjectId=display_object_id)


def video(cameras: Sequence[str], *, title: str | None = None, description: str | None = None) -> dict[str, Any]:
    """Camera image streams, shown as video."""
    return _component("VIDEO", title, description, cameras=list(cameras))


def select(stream: str, target: str, *, title: str | None = None, description: str | None = None) -> dict[str, Any]:
    """A drop-down of a stream's values that sets the configuration key ``target`` (a JSON pointer)."""
    return _component("SELECT", title, description, stream=stream, onchange={"target": target})
