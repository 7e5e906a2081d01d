"""The catalog's database: one SQLite file (the standard library's), or memory.

One row a log: its name, kind, where it is and its version (what says it
changed: a folder's modification times, a store listing's ETags), the state
of its facts (found, indexed, or the error that indexing it met) and the
facts themselves, a column each of :data:`~xviz_server.catalog.columns.COLUMNS`.
Stream names are kept apart (one row a name, one a log's stream) so that a
search by stream uses an index.

A file that is not a database, one of another :data:`SCHEMA` version, or one
whose table of logs has other columns than those declared (a column added or
dropped since it was made), is deleted and built again (with one warning).
When the file cannot be written (a full disk, a file-size limit, a read-only
state directory), the catalog moves to memory with what it held, with one
warning, and the server goes on serving.

Every method blocks: callers run them in the I/O threads. One connection
serves every thread, one call at a time.
"""

from __future__ import annotations

import contextlib
import logging
import sqlite3
import threading
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import orjson

from .columns import COLUMNS

__all__ = ["SCHEMA", "FILE_NAME", "CatalogDB", "Row", "FOUND", "WAITING", "INDEXED", "FAILED"]

logger = logging.getLogger(__name__)

#: The version of the tables below; a file of another version is built again.
SCHEMA = 1
#: The database's file in the state directory.
FILE_NAME = "catalog.sqlite3"

#: States of a log's facts: found (to index), waiting (a log folder without its index yet), indexed, failed.
FOUND, WAITING, INDEXED, FAILED = "found", "waiting", "indexed", "failed"

#: The columns of a log's facts.
_FACTS = tuple(column.name for column in COLUMNS)
_JSON = frozenset(column.name for column in COLUMNS if column.json)

_TABLES = f"""
CREATE TABLE logs (
    id INTEGER PRIMARY KEY,
    name TEXT NOT NULL UNIQUE,
    root TEXT NOT NULL,
    place TEXT NOT NULL,
    version TEXT NOT NULL,
    state TEXT NOT NULL,
    kind TEXT NOT NULL,
    {", ".join(f"{column.name} {column.sql}" for column in COLUMNS)}
);
CREATE INDEX logs_state ON logs (state);
CREATE TABLE stream_names (id INTEGER PRIMARY KEY, name TEXT NOT NULL UNIQUE);
CREATE TABLE log_streams (stream INTEGER NOT NULL, log INTEGER NOT NULL, PRIMARY KEY (stream, log)) WITHOUT ROWID;
CREATE INDEX log_streams_log ON log_streams (log);
PRAGMA user_version = {SCHEMA};
"""

#: The indexes of the sorts and of time searches. A new file gets them once its first build is done
#: (:meth:`CatalogDB.sort_indexes`): kept up to date during it, they would slow each of its writes.
SORT_INDEXES = {column.sort_index: f"{column.name}, name" for column in COLUMNS if column.sort_index}


@dataclass(frozen=True)
class Row:
    """What discovery says of a log: its name, the root it is under, where it is, its version and kind."""

    name: str
    root: str
    place: str
    version: str
    kind: str


class CatalogDB:
    """The catalog's tables, in the file ``path`` or (``None``) in memory."""

    def __init__(self, path: Path | None) -> None:
        self.path = path
        self._lock = threading.Lock()
        #: Whether the catalog is in memory although a file was asked for.
        self.fell_back = False
        self._connection = self._open()
        self._stream_ids: dict[str, int] = dict(
            self._connection.execute("SELECT name, id FROM stream_names").fetchall()
        )
        self._sorted = self._has_sort_indexes()

    # -- opening ------------------------------------------------------------

    def _open(self) -> sqlite3.Connection:
        if self.path is None:
            return self._create(sqlite3.connect(":memory:", check_same_thread=False))
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            connection = sqlite3.connect(self.path, check_same_thread=False)
            try:
                version = connection.execute("PRAGMA user_version").fetchone()[0]
                if version == SCHEMA:
                    connection.execute("SELECT count(*) FROM logs").fetchone()
                    if not (differ := _columns(connection) ^ _declared_columns()):
                        return self._tune(connection)
                    names = sorted({column[0] for column in differ})
                    reason = f"its columns differ from this server's in {', '.join(names)}"
                else:
                    reason = f"it is of version {version}, this server's is {SCHEMA}"
            except sqlite3.DatabaseError as exc:
                reason = f"it is unreadable ({exc})"
            connection.close()
            if reason.startswith("it is of version 0") and self.path.stat().st_size == 0:
                reason = ""  # a new file
            else:
                logger.warning("catalog %s: %s; building it again from the logs", self.path, reason)
            for suffix in ("", "-wal", "-shm", "-journal"):
                Path(f"{self.path}{suffix}").unlink(missing_ok=True)
            return self._create(self._tune(sqlite3.connect(self.path, check_same_thread=False)))
        except (OSError, sqlite3.Error) as exc:
            logger.warning(
                "catalog %s cannot be kept on disk (%s): keeping it in memory until the server stops", self.path, exc
            )
            self.fell_back = True
            return self._create(sqlite3.connect(":memory:", check_same_thread=False))

    @staticmethod
    def _tune(connection: sqlite3.Connection) -> sqlite3.Connection:
        connection.execute("PRAGMA journal_mode = WAL")
        connection.execute("PRAGMA synchronous = NORMAL")
        return connection

    @staticmethod
    def _create(connection: sqlite3.Connection) -> sqlite3.Connection:
        connection.executescript(_TABLES)
        return connection

    def _to_memory(self, exc: sqlite3.Error) -> None:
        """Move the catalog to memory with what it holds, after ``exc`` refused a write to the file."""
        logger.warning(
            "catalog %s cannot be written (%s): keeping it in memory until the server stops; free space in the state directory",
            self.path,
            exc,
        )
        memory = sqlite3.connect(":memory:", check_same_thread=False)
        try:
            self._connection.rollback()
            self._connection.backup(memory)
        except sqlite3.Error:
            memory.close()
            memory = self._create(sqlite3.connect(":memory:", check_same_thread=False))
        self._connection.close()
        self._connection = memory
        self._stream_ids = dict(memory.execute("SELECT name, id FROM stream_names").fetchall())
        self._sorted = self._has_sort_indexes()
        self.fell_back = True

    def _write(self, statements: Any, *args: Any) -> Any:
        """Run ``statements(connection, *args)`` in one transaction; in memory from then on if the file refuses it."""
        with self._lock:
            for _ in range(2):
                try:
                    with self._connection:
                        return statements(self._connection, *args)
                except sqlite3.OperationalError as exc:
                    if self.fell_back or self.path is None:
                        raise
                    self._to_memory(exc)
            raise AssertionError("unreachable")

    def close(self) -> None:
        with self._lock:
            self._connection.close()

    def _has_sort_indexes(self) -> bool:
        marks = ",".join("?" * len(SORT_INDEXES))
        query = f"SELECT count(*) FROM sqlite_master WHERE type = 'index' AND name IN ({marks})"
        return bool(self._connection.execute(query, list(SORT_INDEXES)).fetchone()[0] == len(SORT_INDEXES))

    @property
    def sorted(self) -> bool:
        """Whether the indexes of :data:`SORT_INDEXES` are made."""
        return self._sorted

    def sort_indexes(self) -> bool:
        """Make the indexes of :data:`SORT_INDEXES` that are missing (once a first build is done); whether any was."""
        if self._sorted:
            return False

        def create(connection: sqlite3.Connection) -> None:
            for name, columns in SORT_INDEXES.items():
                connection.execute(f"CREATE INDEX IF NOT EXISTS {name} ON logs ({columns})")

        self._write(create)
        self._sorted = True
        return True

    # -- discovery ----------------------------------------------------------

    def versions(self, names: Sequence[str]) -> dict[str, tuple[str, str]]:
        """Root and version of each of ``names`` the catalog holds."""
        result: dict[str, tuple[str, str]] = {}
        with self._lock:
            for start in range(0, len(names), 500):
                chunk = names[start : start + 500]
                marks = ",".join("?" * len(chunk))
                for name, root, version in self._connection.execute(
                    f"SELECT name, root, version FROM logs WHERE name IN ({marks})", chunk
                ):
                    result[name] = (root, version)
        return result

    def places(self, root: str, after: str = "", limit: int = 1000) -> list[tuple[str, str, str, str]]:
        """Name, place, version and state of the logs of ``root``, in name order, from after ``after``."""
        with self._lock:
            return self._connection.execute(
                "SELECT name, place, version, state FROM logs WHERE root = ? AND name > ? ORDER BY name LIMIT ?",
                (root, after, limit),
            ).fetchall()

    def found(self, rows: Iterable[Row]) -> None:
        """Add logs found, or mark changed ones found again (their old facts stay until new ones come)."""

        def insert(connection: sqlite3.Connection, rows: list[Row]) -> None:
            connection.executemany(
                "INSERT INTO logs (name, root, place, version, state, kind) VALUES (?, ?, ?, ?, ?, ?) "
                "ON CONFLICT (name) DO UPDATE SET root = excluded.root, place = excluded.place, "
                "version = excluded.version, kind = excluded.kind, "
                "state = CASE WHEN logs.version = excluded.version THEN logs.state ELSE excluded.state END",
                [(row.name, row.root, row.place, row.version, FOUND, row.kind) for row in rows],
            )

        self._write(insert, list(rows))

    def remove(self, names: Iterable[str]) -> int:
        """Remove logs (and their streams); how many there were."""

        def delete(connection: sqlite3.Connection, names: list[str]) -> int:
            removed = 0
            for name in names:
                row = connection.execute("SELECT id FROM logs WHERE name = ?", (name,)).fetchone()
                if row is not None:
                    connection.execute("DELETE FROM log_streams WHERE log = ?", row)
                    connection.execute("DELETE FROM logs WHERE id = ?", row)
                    removed += 1
            return removed

        return int(self._write(delete, list(names)))

    def remove_below(self, root: str, prefix: str) -> list[str]:
        """Remove the logs of ``root`` named ``prefix`` or below ``prefix/`` (a folder that went; all for ``""``); their names."""
        with self._lock:
            names = [
                name
                for (name,) in self._connection.execute(
                    "SELECT name FROM logs WHERE root = ? AND (? = '' OR name = ? OR (name > ? AND name < ?))",
                    (root, prefix, prefix, f"{prefix}/", f"{prefix}0"),
                )
            ]
        self.remove(names)
        return names

    def keep_roots(self, roots: Sequence[str]) -> int:
        """Remove the logs of roots no longer served; how many."""
        with self._lock:
            marks = ",".join("?" * len(roots))
            names = [
                name
                for (name,) in self._connection.execute(
                    f"SELECT name FROM logs WHERE root NOT IN ({marks})", list(roots)
                )
            ]
        return self.remove(names)

    def pending(self, limit: int) -> list[tuple[str, str, str, str, str]]:
        """Up to ``limit`` logs found and not yet indexed: name, root, place, version, kind."""
        with self._lock:
            return self._connection.execute(
                "SELECT name, root, place, version, kind FROM logs WHERE state = ? LIMIT ?", (FOUND, limit)
            ).fetchall()

    def mark(self, names: Iterable[str], state: str) -> None:
        """Set the state of logs (:data:`WAITING`, or :data:`FOUND` to index them again)."""
        self._write(
            lambda connection, rows: connection.executemany("UPDATE logs SET state = ? WHERE name = ?", rows),
            [(state, name) for name in names],
        )

    def waiting(self) -> list[tuple[str, str, str]]:
        """The logs waiting for their index: name, place, version."""
        with self._lock:
            return self._connection.execute(
                "SELECT name, place, version FROM logs WHERE state = ?", (WAITING,)
            ).fetchall()

    def place(self, name: str) -> tuple[str, str, str] | None:
        """Root, place and version of the log ``name``, if the catalog holds it."""
        with self._lock:
            return self._connection.execute("SELECT root, place, version FROM logs WHERE name = ?", (name,)).fetchone()

    def indexed(self, results: Iterable[tuple[str, str, dict[str, Any]]]) -> None:
        """Store facts: ``(name, version, facts)``, each only if the log is still at that version.

        ``facts`` has the names of :data:`~xviz_server.catalog.columns.COLUMNS`
        it knows; with ``error`` the log is marked failed.
        """

        def store(connection: sqlite3.Connection, results: list[tuple[str, str, dict[str, Any]]]) -> None:
            ids: dict[tuple[str, str], int] = {}
            for start in range(0, len(results), 500):
                chunk = [name for name, _, _ in results[start : start + 500]]
                query = f"SELECT name, version, id FROM logs WHERE name IN ({','.join('?' * len(chunk))})"
                for name, version, log in connection.execute(query, chunk):
                    ids[name, version] = log
            # Those changed or removed meanwhile are indexed again, or not at all.
            stored = [(ids[name, version], facts) for name, version, facts in results if (name, version) in ids]
            assignments = ", ".join(f"{key} = ?" for key in _FACTS)
            connection.executemany(
                f"UPDATE logs SET state = ?, {assignments} WHERE id = ?",
                [
                    (
                        FAILED if facts.get("error") else INDEXED,
                        *(_column(key, facts.get(key)) for key in _FACTS),
                        log,
                    )
                    for log, facts in stored
                ],
            )
            connection.executemany("DELETE FROM log_streams WHERE log = ?", [(log,) for log, _ in stored])
            names = {stream for _, facts in stored for stream in facts.get("streams") or ()}
            unknown = [stream for stream in names if stream not in self._stream_ids]
            connection.executemany(
                "INSERT OR IGNORE INTO stream_names (name) VALUES (?)", [(stream,) for stream in unknown]
            )
            for start in range(0, len(unknown), 500):
                chunk = unknown[start : start + 500]
                query = f"SELECT name, id FROM stream_names WHERE name IN ({','.join('?' * len(chunk))})"
                self._stream_ids.update(connection.execute(query, chunk).fetchall())
            connection.executemany(
                "INSERT OR IGNORE INTO log_streams (stream, log) VALUES (?, ?)",
                [(self._stream_ids[stream], log) for log, facts in stored for stream in facts.get("streams") or ()],
            )

        self._write(store, list(results))

    # -- questions ----------------------------------------------------------

    def counts(self) -> tuple[int, int]:
        """How many logs are indexed (or failed), and how many are found in all."""
        with self._lock:
            pending, total = self._connection.execute(
                "SELECT (SELECT count(*) FROM logs WHERE state IN (?, ?)), (SELECT count(*) FROM logs)",
                (FOUND, WAITING),
            ).fetchone()
        return total - pending, total

    def names(self, offset: int, limit: int) -> list[str]:
        """Names in order, from ``offset``."""
        with self._lock:
            return [
                name
                for (name,) in self._connection.execute(
                    "SELECT name FROM logs ORDER BY name LIMIT ? OFFSET ?", (limit, offset)
                )
            ]

    def select(self, where: str, parameters: Sequence[Any], order: str, limit: int) -> list[dict[str, Any]]:
        """The logs ``WHERE where ORDER BY order LIMIT limit``, as dictionaries of their columns."""
        sql = f"SELECT name, state, kind, {', '.join(_FACTS)} FROM logs {where and f'WHERE {where}'} ORDER BY {order} LIMIT ?"
        with self._lock:
            cursor = self._connection.execute(sql, (*parameters, limit))
            columns = [column[0] for column in cursor.description]
            rows = cursor.fetchall()
        return [_decoded(dict(zip(columns, row))) for row in rows]

    def longest(self) -> float | None:
        """The longest duration of a log (from its index: no scan)."""
        with self._lock:
            return self._connection.execute("SELECT max(duration) FROM logs").fetchone()[0]

    def stream_id(self, stream: str) -> int | None:
        """The id of a stream name, if any log has it."""
        with self._lock:
            row = self._connection.execute("SELECT id FROM stream_names WHERE name = ?", (stream,)).fetchone()
        return None if row is None else int(row[0])


def _columns(connection: sqlite3.Connection) -> set[tuple[str, str, int, int]]:
    """The columns of the table ``logs``: name, type, whether not null, place in the primary key."""
    return {
        (name, kind, notnull, key) for _, name, kind, notnull, _, key in connection.execute("PRAGMA table_info(logs)")
    }


def _declared_columns() -> set[tuple[str, str, int, int]]:
    """The columns of the table ``logs`` that :data:`_TABLES` makes."""
    with contextlib.closing(sqlite3.connect(":memory:")) as memory:
        memory.executescript(_TABLES)
        return _columns(memory)


def _column(key: str, value: Any) -> Any:
    return orjson.dumps(value).decode() if key in _JSON and value is not None else value


def _decoded(row: dict[str, Any]) -> dict[str, Any]:
    for key in _JSON:
        if row.get(key) is not None:
            row[key] = orjson.loads(row[key])
    return row
