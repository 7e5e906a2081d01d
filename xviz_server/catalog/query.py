"""The query of ``GET /api/logs``: its parameters checked, as SQL, and its cursor.

Parameters (each at most once; others, like ``token``, are left alone):

* ``q``: a substring of the name or a column searched (the description), any case;
* ``stream``: a stream the log has (its exact name);
* ``kind``: one kind or several, comma-separated (see :func:`~xviz_server.catalog.scan.listed_kinds`);
* ``from``, ``to``: seconds; the log's time range overlaps them;
* ``min_duration``: seconds;
* ``sort``: :data:`SORTS`, ``-`` first for the reverse (``-start_time``);
  logs not yet indexed come first, last in reverse;
* ``limit``: logs a page, 1 to :data:`MAX_LIMIT` (default :data:`LIMIT`);
* ``cursor``: the ``next`` of the page before, as it was given.

Paging is by keyset: a cursor holds the sort key and name of the last log
of its page, so that a page costs the same however deep it is, and logs
added or removed meanwhile move no other log between pages.
"""

from __future__ import annotations

import base64
import binascii
from dataclasses import dataclass
from typing import Any

import orjson

from ..exceptions import QueryError
from ..params import seconds, single
from .columns import COLUMNS
from .scan import listed_kinds

__all__ = ["SORTS", "LIMIT", "MAX_LIMIT", "Query", "parse_query"]

#: Orders of a listing: by name, or by a fact then name (the columns with an index to sort by).
SORTS = ("name", *(column.name for column in COLUMNS if column.sort_index))
#: What ``q`` looks in.
_SEARCHED = ("name", *(column.name for column in COLUMNS if column.searched))
LIMIT = 100
MAX_LIMIT = 1000
#: Longest ``q`` and ``stream``, in characters.
MAX_TEXT = 500
_INT64 = (-(2**63), 2**63 - 1)
_NUMBERS = ("from", "to", "min_duration")
_KNOWN = ("q", "stream", "kind", "from", "to", "min_duration", "sort", "limit", "cursor")


@dataclass(frozen=True)
class Query:
    """A checked query of the catalog."""

    q: str | None = None
    stream: str | None = None
    kinds: tuple[str, ...] = ()
    start: float | None = None  # "from"
    end: float | None = None  # "to"
    min_duration: float | None = None
    sort: str = "name"
    descending: bool = False
    limit: int = LIMIT
    after: tuple[Any, str] | None = None  # the cursor: sort key and name of the last log shown

    @property
    def first_page(self) -> bool:
        return self.after is None

    def where(self, stream_id: int | None, longest: float | None) -> tuple[str, list[Any]]:
        """The SQL condition and its parameters.

        ``stream_id`` is the id of :attr:`stream`, if any log has it;
        ``longest`` the longest duration of a log, which bounds where a log
        that overlaps ``from`` can start (so that the start times' index
        finds the candidates of a time range).
        """
        conditions: list[str] = []
        parameters: list[Any] = []
        if self.q is not None:
            pattern = "%" + self.q.replace("\\", "\\\\").replace("%", "\\%").replace("_", "\\_") + "%"
            conditions.append("(" + " OR ".join(f"{name} LIKE ? ESCAPE '\\'" for name in _SEARCHED) + ")")
            parameters += [pattern] * len(_SEARCHED)
        if self.stream is not None:
            conditions.append("id IN (SELECT log FROM log_streams WHERE stream = ?)")
            parameters.append(-1 if stream_id is None else stream_id)
        if self.kinds:
            conditions.append(f"kind IN ({','.join('?' * len(self.kinds))})")
            parameters += self.kinds
        if self.start is not None:
            conditions.append("end_time >= ? AND start_time >= ?")
            parameters += [self.start, self.start - (longest or 0.0)]
        if self.end is not None:
            conditions.append("start_time <= ?")
            parameters.append(self.end)
        if self.min_duration is not None:
            conditions.append("duration >= ?")
            parameters.append(self.min_duration)
        if self.after is not None:
            condition, values = self._after()
            conditions.append(condition)
            parameters += values
        return " AND ".join(conditions), parameters

    def _after(self) -> tuple[str, list[Any]]:
        key, name = self.after  # type: ignore[misc]
        if self.sort == "name":
            return ("name < ?" if self.descending else "name > ?"), [name]
        column = self.sort  # SQL sorts NULL (a log not yet indexed) first
        if not self.descending:
            if key is None:
                return f"(({column} IS NULL AND name > ?) OR {column} IS NOT NULL)", [name]
            return f"({column}, name) > (?, ?)", [key, name]
        if key is None:
            return f"({column} IS NULL AND name < ?)", [name]
        return f"(({column}, name) < (?, ?) OR {column} IS NULL)", [key, name]

    def order(self) -> str:
        """The SQL ordering: the reverse of the ascending one when descending (an index serves both)."""
        direction = " DESC" if self.descending else ""
        return f"name{direction}" if self.sort == "name" else f"{self.sort}{direction}, name{direction}"

    def cursor(self, last: dict[str, Any]) -> str:
        """The cursor of the page after the one that ends with the log ``last``."""
        sort = f"-{self.sort}" if self.descending else self.sort
        text = orjson.dumps([sort, None if self.sort == "name" else last.get(self.sort), last["name"]])
        return base64.urlsafe_b64encode(text).decode().rstrip("=")


def parse_query(parameters: dict[str, list[str]]) -> Query:
    """The query given by URL parameters (each name with its values); raises :class:`~xviz_server.exceptions.QueryError`."""
    values = single(parameters, _KNOWN)
    for name in ("q", "stream"):
        if name in values and (len(values[name]) > MAX_TEXT or not values[name]):
            raise QueryError(name, f"give from 1 to {MAX_TEXT} characters")
    numbers = {
        name: seconds(name, values[name], at_least=0.0 if name == "min_duration" else None)
        for name in _NUMBERS
        if name in values
    }
    if "from" in numbers and "to" in numbers and numbers["from"] > numbers["to"]:
        raise QueryError("from", f"from ({numbers['from']:g}) is after to ({numbers['to']:g})")
    kinds = tuple(values["kind"].split(",")) if "kind" in values else ()
    known = listed_kinds()
    if unknown := [kind for kind in kinds if kind not in known]:
        raise QueryError("kind", f"unknown kind {unknown[0][:50]!r}; kinds are {', '.join(known)}")
    sort = values.get("sort", "name")
    if sort.removeprefix("-") not in SORTS:
        raise QueryError(
            "sort", f"sort by one of {', '.join(SORTS)} (with '-' first for the reverse), not {sort[:50]!r}"
        )
    limit = LIMIT
    if "limit" in values:
        text = values["limit"]
        if not (text.isascii() and text.isdigit() and 1 <= int(text) <= MAX_LIMIT):
            raise QueryError("limit", f"give a whole number from 1 to {MAX_LIMIT}, not {text[:50]!r}")
        limit = int(text)
    after = _read_cursor(values["cursor"], sort) if "cursor" in values else None
    return Query(
        q=values.get("q"),
        stream=values.get("stream"),
        kinds=kinds,
        start=numbers.get("from"),
        end=numbers.get("to"),
        min_duration=numbers.get("min_duration"),
        sort=sort.removeprefix("-"),
        descending=sort.startswith("-"),
        limit=limit,
        after=after,
    )


def _read_cursor(text: str, sort: str) -> tuple[Any, str]:
    try:
        decoded = orjson.loads(base64.urlsafe_b64decode(text + "=" * (-len(text) % 4)))
    except (binascii.Error, ValueError):
        decoded = None
    if not (
        isinstance(decoded, list)
        and len(decoded) == 3
        and isinstance(decoded[2], str)
        and (decoded[1] is None or (isinstance(decoded[1], (int, float)) and not isinstance(decoded[1], bool)))
    ):
        raise QueryError("cursor", "not a cursor this server gave: pass the 'next' of the page before, as it was")
    if decoded[0] == "name" and decoded[1] is not None:
        raise QueryError("cursor", "not a cursor this server gave: pass the 'next' of the page before, as it was")
    if isinstance(decoded[1], int) and not _INT64[0] <= decoded[1] <= _INT64[1]:  # SQLite's integers are 64-bit
        raise QueryError(
            "cursor",
            f"its sort key {str(decoded[1])[:50]} is out of SQLite's 64-bit range: not a cursor this server gave",
        )
    if decoded[0] != sort:
        raise QueryError(
            "cursor",
            f"this cursor pages a listing sorted by {str(decoded[0])[:50]!r}, not {sort[:50]!r}: give the same sort",
        )
    return decoded[1], decoded[2]
