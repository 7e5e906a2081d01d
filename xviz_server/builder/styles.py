"""Checking styles and colours before they reach a log.

The schema (``schema/style/``, which agrees with the published
``@xviz/schema``) says which properties exist, which may be set per object
and that a style needs at least one property besides ``height``; the
specification's property tables (§5.2) say which apply to which primitive
type. A style that breaks either is refused with a message naming the
stream, the field and the property, because a viewer would otherwise ignore
it without a word (``@xviz/parser`` turns a colour it cannot parse into
``null`` and draws the default), and a strict client would refuse the
message.
"""

from __future__ import annotations

import difflib
import json
import math
import re
from collections.abc import Mapping
from functools import cache
from importlib import resources
from typing import Any, NamedTuple

import numpy as np

from ..exceptions import BuilderError
from ..validation import get_validator

__all__ = ["check_color", "check_style", "PRIMITIVE_STYLES"]

#: The style properties that apply to each primitive type (specification §5.2).
PRIMITIVE_STYLES: dict[str, frozenset[str]] = {
    "CIRCLE": frozenset(
        {
            "radius",
            "radius_min_pixels",
            "radius_max_pixels",
            "filled",
            "stroked",
            "fill_color",
            "stroke_color",
            "stroke_width",
            "stroke_width_min_pixels",
            "stroke_width_max_pixels",
            "opacity",
        }
    ),
    "POINT": frozenset({"radius_pixels", "fill_color", "point_color_mode", "point_color_domain", "opacity"}),
    "POLYGON": frozenset(
        {
            "extruded",
            "height",
            "filled",
            "stroked",
            "fill_color",
            "stroke_color",
            "stroke_width",
            "stroke_width_min_pixels",
            "stroke_width_max_pixels",
            "opacity",
        }
    ),
    "POLYLINE": frozenset(
        {"stroke_color", "stroke_width", "stroke_width_min_pixels", "stroke_width_max_pixels", "opacity"}
    ),
    "STADIUM": frozenset({"fill_color", "radius", "radius_min_pixels", "radius_max_pixels", "opacity"}),
    "TEXT": frozenset(
        {
            "font_family",
            "font_weight",
            "fill_color",
            "text_size",
            "text_rotation",
            "text_anchor",
            "text_baseline",
            "opacity",
        }
    ),
    "IMAGE": frozenset(),
}

_COLOR_PROPERTIES = frozenset({"fill_color", "stroke_color"})

# What the published client (the ``color`` package) draws but the schema
# refuses: CSS colour names and functions.
_CSS_COLOR = re.compile(r"[a-zA-Z]+|(?:rgba?|hsla?|hwb)\(.*\)", re.DOTALL)
_HEX = re.compile(r"#(?:[0-9a-fA-F]{3,4}|[0-9a-fA-F]{6}|[0-9a-fA-F]{8})")
_COLOR_FORMS = "'#RRGGBB[AA]', '#RGB[A]' or [r, g, b(, a)] with channels 0-255"


def check_color(where: str, value: Any) -> str | list[float]:
    """Return ``value`` as a colour XVIZ carries, or raise :class:`BuilderError` naming ``where``.

    A colour is a hex string (``"#RRGGBB[AA]"``, ``"#RGB[A]"``) or a list of
    3 or 4 channels in 0-255 (a tuple or numpy array becomes a list). CSS
    colour names and functions (``"red"``, ``"rgb(255, 0, 0)"``) are refused:
    the published client draws them, but the published schema refuses them.
    """
    if isinstance(value, str):
        if _HEX.fullmatch(value):
            return value
        if _CSS_COLOR.fullmatch(value):
            raise BuilderError(
                f"{where}: {value!r} is not a colour the XVIZ schema takes (the client draws CSS colour names and "
                f"functions, the schema refuses them); write {_COLOR_FORMS}"
            )
        raise BuilderError(f"{where}: {value!r} is not a colour; write {_COLOR_FORMS}")
    if isinstance(value, (list, tuple, np.ndarray)):
        channels = np.asarray(value)
        if (
            channels.ndim == 1
            and len(channels) in (3, 4)
            and (np.issubdtype(channels.dtype, np.integer) or np.issubdtype(channels.dtype, np.floating))
            and np.isfinite(channels).all()
            and channels.min() >= 0
            and channels.max() <= 255
        ):
            return channels.tolist()
    raise BuilderError(f"{where}: {value!r} is not a colour; write {_COLOR_FORMS}")


def check_style(
    where: str, style: Mapping[str, Any], primitive_type: str | None, *, per_object: bool
) -> dict[str, Any]:
    """Return a checked copy of ``style``, or raise :class:`BuilderError` naming ``where`` and the property.

    ``primitive_type`` limits the properties to those that apply to it (none
    when unknown, as for annotations); ``per_object`` refuses the properties
    that only a stream style may set. Colours are checked by
    :func:`check_color`, other values by the schema; numpy scalars become
    Python numbers. A style needs at least one property besides ``height``
    (a colour, a width...): the schema refuses one of ``height`` alone.
    """
    if not isinstance(style, Mapping):
        raise BuilderError(f"{where}: a style is a mapping of property names to values, not {type(style).__name__}")
    properties = _schema_properties()
    allowed = properties.per_object if per_object else properties.per_stream
    if primitive_type is not None:
        allowed = allowed & PRIMITIVE_STYLES[primitive_type]
    checked: dict[str, Any] = {}
    for name, value in style.items():
        if name not in allowed:
            raise BuilderError(
                _unknown_property(where, name, primitive_type, per_object, allowed, properties.per_stream)
            )
        if isinstance(value, np.generic):
            value = value.item()
        if name in _COLOR_PROPERTIES:
            value = check_color(f"{where}.{name}", value)
        elif isinstance(value, float) and not math.isfinite(value):
            raise BuilderError(f"{where}.{name}: {value!r} is not a finite number")
        elif name in properties.numbers and _within(value, properties.numbers[name]):
            pass  # all the schema asks of it
        elif problems := _property_problems(name, value):
            raise BuilderError(f"{where}.{problems[0].removeprefix('$.')}")
        checked[name] = value
    needs = properties.object_needs if per_object else properties.stream_needs
    if not needs & checked.keys():
        given = f" beside {', '.join(checked)}" if checked else ""
        hint = " (a height of its own goes with the object's colour)" if per_object and "height" in checked else ""
        raise BuilderError(
            f"{where}: a style needs one of {', '.join(sorted(needs & allowed))}{given}: the XVIZ schema refuses one "
            f"without{hint}"
        )
    return checked


def _property_problems(name: str, value: Any) -> list[str]:
    """What the schema says of one property's value; only the property's own schema is asked."""
    return [
        problem for problem in get_validator().errors("style/stream_value", {name: value}) if problem.startswith("$.")
    ]


def _unknown_property(
    where: str,
    name: str,
    primitive_type: str | None,
    per_object: bool,
    allowed: frozenset[str],
    stream_properties: frozenset[str],
) -> str:
    if not isinstance(name, str):
        return f"{where}: property names are strings, not {name!r}"
    if (
        per_object
        and name in stream_properties
        and (primitive_type is None or name in PRIMITIVE_STYLES[primitive_type])
    ):
        return f"{where}: {name!r} can only be set in the stream's style, not per object or per class"
    if primitive_type is not None and name in stream_properties:
        takes = ", ".join(sorted(allowed)) or "no style properties"
        return f"{where}: {name!r} does not apply to {primitive_type} primitives (they take {takes})"
    close = difflib.get_close_matches(name, sorted(allowed), n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    return f"{where}: no style property {name!r}{hint}"


def _within(value: Any, bounds: tuple[float, float]) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and bounds[0] <= value <= bounds[1]


class _Properties(NamedTuple):
    """What the schema says of style properties."""

    per_object: frozenset[str]  #: the properties of an object (inline or class) style
    per_stream: frozenset[str]  #: the properties of a stream style
    object_needs: frozenset[str]  #: an object style needs one of these
    stream_needs: frozenset[str]  #: a stream style needs one of these
    numbers: dict[str, tuple[float, float]]  #: the bounds of the plain numbers


@cache
def _schema_properties() -> _Properties:
    """The style properties, read from the schema.

    A plain number is a property whose schema asks only for a number, at
    most within a minimum and a maximum; a finite value within them needs no
    further check. What a style needs is the ``anyOf`` of ``required``
    properties of its schema.
    """
    folder = resources.files("xviz_server.schema") / "style"
    object_schema = json.loads((folder / "object_value.json").read_text("utf-8"))
    stream_schema = json.loads((folder / "stream_value.json").read_text("utf-8"))
    schemas = {**object_schema["$defs"]["per_object"]["properties"], **stream_schema["properties"]}
    numbers = {
        name: (schema.get("minimum", -math.inf), schema.get("maximum", math.inf))
        for name, schema in schemas.items()
        if schema.get("type") == "number" and set(schema) <= {"type", "minimum", "maximum", "description"}
    }
    per_object = frozenset(object_schema["$defs"]["per_object"]["properties"])

    def needs(schema: dict[str, Any]) -> frozenset[str]:
        return frozenset(name for alternative in schema["anyOf"] for name in alternative["required"])

    return _Properties(
        per_object,
        per_object | frozenset(stream_schema["properties"]),
        needs(object_schema),
        needs(stream_schema),
        numbers,
    )
