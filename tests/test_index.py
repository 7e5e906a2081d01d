"""The time index: ranges and instants by binary search."""

from __future__ import annotations

import numpy as np
import pytest

from xviz_server.exceptions import DecodeError
from xviz_server.timeindex import TimeIndex


def test_reference_index_and_range_queries():
    index = TimeIndex.from_reference({"timing": [[100 + i, 100 + i, i, f"{i + 2}-frame"] for i in range(10)]})
    assert (index.start_time, index.end_time, len(index)) == (100, 109, 10)
    assert index.frames[index.range(102, 104)].tolist() == [2, 3, 4]
    assert index.frames[index.range(102.5, 104.5)].tolist() == [3, 4]
    assert index.frames[index.range(None, 101)].tolist() == [0, 1]
    assert index.frames[index.range(108, None)].tolist() == [8, 9]
    assert index.range(200, 300).tolist() == [] and index.range(0, 50).tolist() == []
    assert index.range(105, 104).tolist() == []


def test_spans_overlapping_a_range_are_included():
    index = TimeIndex.from_spans([(0, 10, 0), (5, 6, 1), (11, 12, 2)])
    assert index.frames[index.range(8, 9)].tolist() == [0]  # frame 0 spans 0-10
    assert index.frames[index.range(5.5, 11)].tolist() == [0, 1, 2]


def test_instants():
    index = TimeIndex.from_spans([(t, t, i) for i, t in enumerate([1.0, 2.0, 3.0])])
    assert index.at(0.5) is None
    assert index.at(1.0) == 0 and index.at(2.5) == 1 and index.at(99) == 2


def test_unsorted_spans_are_put_in_time_order():
    index = TimeIndex.from_spans([(3, 3, 2), (1, 1, 0), (2, 2, 1)])
    assert index.frames.tolist() == [0, 1, 2] and index.start.tolist() == [1, 2, 3]


def test_empty_index():
    index = TimeIndex.from_spans([])
    assert (len(index), index.start_time, index.end_time, index.at(5)) == (0, None, None, None)
    assert index.range().tolist() == []


def test_reference_index_in_any_row_order_matches_spans():
    rows = [[5, 6, 3, "5-frame"], [1, 1.5, 0.0, "2-frame"], [3, 3, 2, "4-frame"], [3, 4, 1, "3-frame"]]
    index = TimeIndex.from_reference({"timing": rows})
    spans = TimeIndex.from_spans((start, end, int(frame)) for start, end, frame, _ in rows)
    assert index.frames.tolist() == spans.frames.tolist() == [0, 1, 2, 3]
    assert index.start.tolist() == spans.start.tolist() == [1, 3, 3, 5]
    assert index.end.tolist() == spans.end.tolist() == [1.5, 4, 3, 6]
    assert index.frames.dtype == np.int64


@pytest.mark.parametrize(
    "document, where",
    [
        ({"startTime": 1}, "'timing' must be a list"),
        ({"timing": [[1, 2]]}, r"timing\[0\] is not"),
        ({"timing": [[1, 1, 0, "2-frame"], [2, "x", 1, "3-frame"]]}, r"timing\[1\] is not"),
        ({"timing": [[1, 1, 0.5, "2-frame"]]}, r"timing\[0\] is not"),
        ({"timing": [[1, 1, -1, "2-frame"]]}, r"timing\[0\] is not"),
        ({"timing": [[1, 1, 0, "2-frame"], [2, 2, True, "3-frame"]]}, r"timing\[1\] is not"),
        ({"timing": [[1, 1, 0, "2-frame"], [float("nan"), 2, 1, "3-frame"]]}, r"timing\[1\] is not"),
        ({"timing": [[1, 1, 0, "2-frame"], [10**400, 2, 1, "3-frame"]]}, r"timing\[1\] is not"),
        ({"timing": [[1, 1, 0, "2-frame"], "abc"]}, r"timing\[1\] is not"),
        ([1, 2], "'timing' must be a list"),
    ],
)
def test_bad_reference_index_names_the_row(document, where):
    with pytest.raises(DecodeError, match=where):
        TimeIndex.from_reference(document)


def test_lookups_stay_logarithmic_on_a_long_log():
    start = np.arange(1_000_000) / 10.0
    index = TimeIndex.from_spans(zip(start, start, range(len(start))))
    assert index.at(50_000.05) == 500_000
    assert index.frames[index.range(99_999.0, None)].tolist() == list(range(999_990, 1_000_000))
