"""The recipes of docs/changes.md, done: a change made in the one place the page names is taken everywhere."""

from __future__ import annotations

import pytest

from xviz_server import datasets
from xviz_server.catalog.query import parse_query
from xviz_server.catalog.scan import listed_kinds, source_kind
from xviz_server.exceptions import QueryError


def test_a_dataset_kind_registered_in_datasets_kinds_is_listed_and_queried(monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(QueryError, match="unknown kind 'lyft'"):
        parse_query({"kind": ["lyft"]})
    monkeypatch.setitem(datasets.KINDS, "lyft", ("lyft", "LyftScene", "is_lyft_scene"))
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
