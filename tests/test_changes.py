"""The recipes of docs/changes.md, done: a change made in the one place the page names is taken everywhere."""

from __future__ import annotations

import base64
import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from xviz_server import datasets
from xviz_server.catalog.columns import COLUMNS
from xviz_server.catalog.facts import facts
from xviz_server.catalog.query import parse_query
from xviz_server.catalog.scan import listed_kinds, source_kind
from xviz_server.codec import Format
from xviz_server.exceptions import QueryError
from xviz_server.timeindex import TimeIndex


def test_a_dataset_kind_registered_in_datasets_kinds_is_listed_and_queried(monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(QueryError, match="unknown kind 'lyft'"):
        parse_query({"kind": ["lyft"]})
    monkeypatch.setitem(datasets.DATASET_KINDS, "lyft", ("lyft", "LyftScene", "is_lyft_scene"))
    assert "lyft" in listed_kinds()
    assert source_kind("lyft", "/data/scene-1") == "lyft"
    assert parse_query({"kind": ["lyft,kitti"]}).kinds == ("lyft", "kitti")


def test_ros_recordings_are_listed_by_their_suffix() -> None:
    assert [source_kind("rosbag", place) for place in ("a.bag", "b.mcap", "c.db3")] == ["bag", "mcap", "bag"]
    assert listed_kinds() == (
        "xviz",
        "kitti",
        "waymo",
        "vista",
        "demo",
        "bag",
        "mcap",
        "nuscenes",
        "argoverse2",
        "pandaset",
    )


ADD_A_COLUMN = textwrap.dedent(
    """
    import importlib, json, logging, sqlite3, sys
    from pathlib import Path
    from xviz_server.catalog import columns, db, indexer, query

    logging.basicConfig(format="%(levelname)s %(message)s")
    path = Path(sys.argv[1])
    db.CatalogDB(path).close()  # a catalog file made before the column was added

    columns.COLUMNS += (columns.Column("cameras", "INTEGER", sort_index="logs_cameras"),)  # the one declaration
    for module in (db, query, indexer):
        importlib.reload(module)
    catalog = db.CatalogDB(path)
    catalog.found([db.Row(name, "root", f"/{name}", "1", "xviz") for name in ("a", "b", "c")])
    catalog.indexed([(name, "1", {"kind": "xviz", "frames": 2, "cameras": n}) for name, n in (("a", 2), ("b", 3), ("c", 1))])
    catalog.sort_indexes()
    asked = query.parse_query({"sort": ["-cameras"], "limit": ["2"]})
    rows = catalog.select(*asked.where(None, None), asked.order(), asked.limit + 1)
    with sqlite3.connect(path) as connection:
        indexes = [name for (name,) in connection.execute("SELECT name FROM sqlite_master WHERE type = 'index'")]
    print(json.dumps({"logs": [indexer.summary(row) for row in rows],
                      "next": asked.cursor(rows[1]), "indexes": indexes}))
    """
)


def test_a_catalog_column_declared_in_columns_alone_is_stored_sorted_and_listed(tmp_path: Path) -> None:
    """The recipe: a column added to ``COLUMNS`` (and given by ``facts()``) is in the table, ``?sort=`` and the answer."""
    with pytest.raises(QueryError, match="sort by one of"):
        parse_query({"sort": ["cameras"]})
    done = subprocess.run(
        [sys.executable, "-c", ADD_A_COLUMN, str(tmp_path / "catalog.sqlite3")],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    result = json.loads(done.stdout)
    warnings = [line for line in done.stderr.splitlines() if line.startswith("WARNING")]
    assert len(warnings) == 1 and "columns differ from this server's in cameras; building it again" in warnings[0]
    assert [(log["name"], log["cameras"]) for log in result["logs"]] == [("b", 3), ("a", 2), ("c", 1)]
    assert json.loads(base64.urlsafe_b64decode(result["next"] + "==")) == ["-cameras", 2, "a"]
    assert "logs_cameras" in result["indexes"]


def test_facts_gives_a_value_for_each_declared_column() -> None:
    given = facts(
        "xviz", Format.JSON, {"log_info": {"start_time": 1.0, "end_time": 3.0}}, TimeIndex.from_spans([]), 10, 2.0
    )
    assert set(given) == {"kind"} | {column.name for column in COLUMNS if column.name != "error"}
    assert given["duration"] == 2.0 and given["bytes"] == 10


def test_only_numbers_are_sorted_by() -> None:
    """A cursor holds the sort key of its page's last log, and reads back only a number (see catalog/query.py)."""
    assert all(column.sql in ("INTEGER", "REAL") for column in COLUMNS if column.sort_index)
