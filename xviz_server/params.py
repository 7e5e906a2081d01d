"""URL query parameters read strictly: each named one at most once, numbers in plain decimal.

One reader for every HTTP query the server takes (the catalog's
``GET /api/logs``, an export's ``start``/``end``), so that they refuse the
same things the same way, with a
:class:`~xviz_server.exceptions.QueryError` naming the parameter:

* :func:`single`: the value of each parameter the route knows, refusing one
  given twice (``start=1&start=2``: which one was meant is unknowable);
* :func:`repeated`: the names a query string gives twice, for a reader of
  one value per name (a WebSocket session's URL, on either face), and
  :func:`given_twice`, what the session says of each;
* :func:`seconds`: a number of seconds, written ``[-]digits[.digits][e[±]digits]``
  and finite. Python's ``float`` also takes ``1_000``, `` 5 ``, ``inf`` and
  ``+5``: none of them is a number a client writes on purpose, and ``+``
  is left for times relative to a log's start.
"""

from __future__ import annotations

import math
import re
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from urllib.parse import parse_qsl

from .budget import shown
from .exceptions import QueryError

__all__ = ["single", "seconds", "repeated", "given_twice"]

_NUMBER = re.compile(r"-?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][-+]?[0-9]+)?")
#: Characters of a refused value shown in the error.
SHOWN = 50


def single(parameters: Mapping[str, Sequence[str]], names: Iterable[str]) -> dict[str, str]:
    """The value of each of ``names`` given in ``parameters`` (each name with its values, as
    :func:`urllib.parse.parse_qs` gives them); raises :class:`QueryError` for a name given more than once."""
    values: dict[str, str] = {}
    for name in names:
        given = parameters.get(name)
        if not given:
            continue
        if len(given) > 1:
            raise QueryError(name, "give it at most once")
        values[name] = given[0]
    return values


def repeated(query: str) -> frozenset[str]:
    """The names given more than once in the query string ``query`` (for a reader that takes one value of each)."""
    counts = Counter(name for name, _ in parse_qsl(query, keep_blank_values=True))
    return frozenset(name for name, count in counts.items() if count > 1)


def given_twice(name: str) -> str:
    """What a WebSocket session tells its client of a URL parameter given more than once (see :func:`repeated`):
    refused, and taken as not given."""
    return f"bad connection URL parameter {shown(name)}: give it at most once; it is ignored"


def seconds(name: str, text: str, *, at_least: float | None = None) -> float:
    """``text``, the value of parameter ``name``, as a finite number of seconds (at least ``at_least``);
    raises :class:`QueryError` naming the parameter and the syntax."""
    value = float(text) if _NUMBER.fullmatch(text) else math.nan
    if not math.isfinite(value) or (at_least is not None and value < at_least):
        least = "" if at_least is None else f", at least {at_least:g}"
        raise QueryError(
            name, f"give a finite number of seconds ([-]digits[.digits][e±digits]{least}), not {text[:SHOWN]!r}"
        )
    return value
