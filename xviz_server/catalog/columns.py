"""The catalog's columns: each fact of a log it stores, lists, sorts by and searches, declared once.

Everything else follows :data:`COLUMNS`: :mod:`.db` makes the table, its
writes, its reads and the indexes of the sorts from it (and builds a file
whose columns differ again); :mod:`.query` takes the values of ``sort`` and
what ``q`` searches; :func:`~xviz_server.catalog.indexer.summary` the
fields of a log in ``GET /api/logs`` and ``GET /api/logs/NAME``. A column's
value is what :func:`~xviz_server.catalog.facts.facts` gives under its name
(``None`` where it is not known: then it is left out of the answer).

A log's ``name``, ``kind`` and the columns of its discovery (where it is,
its version, the state of its facts) are not facts: :mod:`.db` keeps them.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Column", "COLUMNS"]


@dataclass(frozen=True)
class Column:
    """One fact of a log: its name (in SQL and in the answers) and what the catalog does with it."""

    name: str
    #: Its SQL type: ``INTEGER``, ``REAL`` or ``TEXT``.
    sql: str
    #: A list or an object, kept as JSON text.
    json: bool = False
    #: The name of the index that serves ``?sort=NAME``, for a column that can be sorted by. Only numbers
    #: can: a cursor holds the sort key of the last log of its page (see :mod:`.query`).
    sort_index: str | None = None
    #: ``q`` looks for its substring in it (as in the name), any case.
    searched: bool = False
    #: Shown in each log of ``GET /api/logs``; else only by ``GET /api/logs/NAME``.
    listed: bool = True


#: The columns, in the order the answers show them.
COLUMNS = (
    Column("format", "TEXT"),
    Column("frames", "INTEGER", sort_index="logs_frames"),
    Column("start_time", "REAL", sort_index="logs_start"),
    Column("end_time", "REAL", sort_index="logs_end"),
    Column("duration", "REAL", sort_index="logs_duration"),
    Column("streams", "TEXT", json=True),
    Column("bytes", "INTEGER", sort_index="logs_bytes"),
    Column("modified", "REAL", sort_index="logs_modified"),
    Column("description", "TEXT", searched=True),
    Column("vehicle", "TEXT"),
    Column("tags", "TEXT", json=True),
    Column("error", "TEXT"),
    Column("detail", "TEXT", json=True, listed=False),
)
