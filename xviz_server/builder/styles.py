"""Checking styles and colours before they reach a log.

The schema (``schema/style/``) says which properties exist and which may be
set per object; the specification's property tables (§5.2) say which apply
to which primitive type. A style that breaks either is refused with a
message naming the stream, the field and the property, because a viewer
would otherwise ignore it without a word: ``@xviz/parser`` turns a colour it
cannot parse into ``null`` and draws the default.
"""

from __future__ import annotations

import difflib
import json
import math
import re
from collections.abc import Mapping
from functools import cache
from importlib import resources
from typing import Any

import numpy as np

from ..exceptions import BuilderError
from ..validation import get_validator

__all__ = ["check_color", "check_style", "PRIMITIVE_STYLES"]

#: The style properties that apply to each primitive type (specification §5.2).
PRIMITIVE_STYLES: dict[str, frozenset[str]] = {
    "CIRCLE": frozenset({
        "radius", "radius_min_pixels", "radius_max_pixels", "filled", "stroked", "fill_color", "stroke_color",
        "stroke_width", "stroke_width_min_pixels", "stroke_width_max_pixels", "opacity",
    }),
    "POINT": frozenset({"radius_pixels", "fill_color", "point_color_mode", "point_color_domain", "opacity"}),
    "POLYGON": frozenset({
        "extruded", "height", "filled", "stroked", "fill_color", "stroke_color", "stroke_width",
        "stroke_width_min_pixels", "stroke_width_max_pixels", "opacity",
    }),
    "POLYLINE": frozenset({"stroke_color", "stroke_width", "stroke_width_min_pixels", "stroke_width_max_pixels", "opacity"}),
    "STADIUM": frozenset({"fill_color", "radius", "radius_min_pixels", "radius_max_pixels", "opacity"}),
    "TEXT": frozenset({
        "font_family", "font_weight", "fill_color", "text_size", "text_rotation", "text_anchor", "text_baseline",
        "opacity",
    }),
    "IMAGE": frozenset(),
}

_COLOR_PROPERTIES = frozenset({"fill_color", "stroke_color"})

# The names the published client (the ``color`` package) understands: CSS
# colour names, lower case, and "transparent".
_CSS_NAMES = frozenset(
    """aliceblue antiquewhite aqua aquamarine azure beige bisque black blanchedalmond blue blueviolet brown
    burlywood cadetblue chartreuse chocolate coral cornflowerblue cornsilk crimson cyan darkblue darkcyan
    darkgoldenrod darkgray darkgreen darkgrey darkkhaki darkmagenta darkolivegreen darkorange darkorchid darkred
    darksalmon darkseagreen darkslateblue darkslategray darkslategrey darkturquoise darkviolet deeppink deepskyblue
    dimgray dimgrey dodgerblue firebrick floralwhite forestgreen fuchsia gainsboro ghostwhite gold goldenrod gray
    green greenyellow grey honeydew hotpink indianred indigo ivory khaki lavender lavenderblush lawngreen
    lemonchiffon lightblue lightcoral lightcyan lightgoldenrodyellow lightgray lightgreen lightgrey lightpink
    lightsalmon lightseagreen lightskyblue lightslategray lightslategrey lightsteelblue lightyellow lime limegreen
    linen magenta maroon mediumaquamarine mediumblue mediumorchid mediumpurple mediumseagreen mediumslateblue
    mediumspringgreen mediumturquoise mediumvioletred midnightblue mintcream mistyrose moccasin navajowhite navy
    oldlace olive olivedrab orange orangered orchid palegoldenrod palegreen paleturquoise palevioletred papayawhip
    peachpuff peru pink plum powderblue purple rebeccapurple red rosybrown royalblue saddlebrown salmon sandybrown
    seagreen seashell sienna silver skyblue slateblue slategray slategrey snow springgreen steelblue tan teal
    thistle tomato turquoise violet wheat white whitesmoke yellow yellowgreen transparent""".split()
)
_HEX = re.compile(r"#(?:[0-9a-fA-F]{3,4}|[0-9a-fA-F]{6}|[0-9a-fA-F]{8})")
_RGB = re.compile(r"rgba?\(\s*\d{1,3}\s*[,\s]\s*\d{1,3}\s*[,\s]\s*\d{1,3}\s*(?:[,/]\s*(?:0|1|0?\.\d+|\d{1,3}%)\s*)?\)")
_COLOR_FORMS = "'#RRGGBB[AA]', '#RGB[A]', [r, g, b(, a)] with channels 0-255, 'rgb(r, g, b)' or a CSS colour name"


def check_color(where: str, value: Any) -> str | list[float]:
    """Return ``value`` as a colour XVIZ carries, or raise :class:`BuilderError` naming ``where``.

    A colour is a hex string (``"#RRGGBB[AA]"``, ``"#RGB[A]"``), a list of 3
    or 4 channels in 0-255 (a tuple or numpy array becomes a list), an
    ``rgb()``/``rgba()`` string or a lower-case CSS colour name. ``hsl()`` and
    ``hwb()`` are refused: the published client reads their numbers as RGB.
    """
    if isinstance(value, str):
        if _HEX.fullmatch(value) or _RGB.fullmatch(value) or value in _CSS_NAMES:
            return value
        if value.lower() in _CSS_NAMES:
            raise BuilderError(f"{where}: colour names are lower case for the client: write {value.lower()!r}")
        if value.startswith(("hsl", "hwb")):
            raise BuilderError(f"{where}: {value!r}: the client reads hsl()/hwb() numbers as RGB; write the colour in hex")
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


def check_style(where: str, style: Mapping[str, Any], primitive_type: str | None, *, per_object: bool) -> dict[str, Any]:
    """Return a checked copy of ``style``, or raise :class:`BuilderError` naming ``where`` and the property.

    ``primitive_type`` limits the properties to those that apply to it (none
    when unknown, as for annotations); ``per_object`` refuses the properties
    that only a stream style may set. Colours are checked by
    :func:`check_color`, other values by the schema; numpy scalars become
    Python numbers.
    """
    if not isinstance(style, Mapping):
        raise BuilderError(f"{where}: a style is a mapping of property names to values, not {type(style).__name__}")
    object_properties, stream_properties, numbers = _schema_properties()
    allowed = object_properties if per_object else stream_properties
    if primitive_type is not None:
        allowed = allowed & PRIMITIVE_STYLES[primitive_type]
    checked: dict[str, Any] = {}
    for name, value in style.items():
        if name not in allowed:
            raise BuilderError(_unknown_property(where, name, primitive_type, per_object, allowed, stream_properties))
        if isinstance(value, np.generic):
            value = value.item()
        if name in _COLOR_PROPERTIES:
            value = check_color(f"{where}.{name}", value)
        elif isinstance(value, float) and not math.isfinite(value):
            raise BuilderError(f"{where}.{name}: {value!r} is not a finite number")
        elif name in numbers and _within(value, numbers[name]):
            pass  # all the schema asks of it
        elif problems := get_validator().errors("style/stream_value", {name: value}):
            raise BuilderError(f"{where}.{problems[0].removeprefix('$.')}")
        checked[name] = value
    return checked


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
    if per_object and name in stream_properties and (primitive_type is None or name in PRIMITIVE_STYLES[primitive_type]):
        return f"{where}: {name!r} can only be set in the stream's style, not per object or per class"
    if primitive_type is not None and name in stream_properties:
        takes = ", ".join(sorted(allowed)) or "no style properties"
        return f"{where}: {name!r} does not apply to {primitive_type} primitives (they take {takes})"
    close = difflib.get_close_matches(name, sorted(allowed), n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    return f"{where}: no style property {name!r}{hint}"


def _within(value: Any, bounds: tuple[float, float]) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and bounds[0] <= value <= bounds[1]


@cache
def _schema_properties() -> tuple[frozenset[str], frozenset[str], dict[str, tuple[float, float]]]:
    """The property names of an object style and of a stream style, and the bounds of the plain numbers.

    Read from the schema. A plain number is a property whose schema asks
    only for a number, at most within a minimum and a maximum; a finite
    value within them needs no further check.
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
    return per_object, per_object | frozenset(stream_schema["properties"]), numbers
