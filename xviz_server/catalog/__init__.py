"""The catalog of logs: every log the server serves, listed, searched and paged without opening one.

* :mod:`.db`: the SQLite database under ``--state-dir`` (or in memory);
* :mod:`.scan`: finding logs under a directory, then what changed, by modification times;
* :mod:`.facts`: what is known of a log, read from its index document and metadata;
* :mod:`.indexer`: the background tasks that keep the database current;
* :mod:`.query`: the parameters of ``GET /api/logs``, as SQL, and its cursor.

Sessions do not wait for it: a session opens the log it names whether the
catalog has indexed it or not (see :class:`~xviz_server.logs.LogShelf`).
"""

from .indexer import Indexer
from .query import Query, parse_query

__all__ = ["Indexer", "Query", "parse_query"]
