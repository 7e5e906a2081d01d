"""Stream filtering and complete-state merging on plain state updates."""

from __future__ import annotations

import numpy as np

from xviz_server.state import complete_state, filter_streams, update_streams


def stream_set(t: float, **streams) -> dict:
    return {"timestamp": t, **streams}


def message(update_type: str, *sets: dict) -> dict:
    return {"type": "xviz/state_update", "data": {"update_type": update_type, "updates": list(sets)}}


SERIES = [{"timestamp": 1.0, "streams": ["/a", "/b", "/c"], "values": {"doubles": [1.0, 2.0, 3.0]}}]


def test_filter_keeps_wanted_streams_and_splits_time_series():
    cloud = np.zeros((5, 3), np.float32)
    original = message(
        "SNAPSHOT",
        stream_set(
            1.0,
            poses={"/pose": {"position": [0, 0, 0]}},
            primitives={"/pts": {"points": [{"points": cloud}]}, "/img": {}},
            time_series=SERIES,
            no_data_streams=["/gone", "/b"],
        ),
    )
    filtered = filter_streams(original, {"/pose", "/b", "/pts"})
    update = filtered["data"]["updates"][0]
    assert update["timestamp"] == 1.0 and filtered["data"]["update_type"] == "SNAPSHOT"
    assert set(update["primitives"]) == {"/pts"} and update["primitives"]["/pts"]["points"][0]["points"] is cloud
    assert update["time_series"] == [{"timestamp": 1.0, "streams": ["/b"], "values": {"doubles": [2.0]}}]
    assert update["no_data_streams"] == ["/b"]
    assert "/img" in original["data"]["updates"][0]["primitives"]  # input untouched
    assert update_streams(filtered["data"]) == {"/pose", "/b", "/pts"}


def test_filter_drops_emptied_containers():
    filtered = filter_streams(
        message("SNAPSHOT", stream_set(1.0, primitives={"/x": {}}, time_series=SERIES)), {"/pose"}
    )
    assert filtered["data"]["updates"] == [{"timestamp": 1.0}]


def test_complete_state_takes_each_stream_from_the_newest_and_stops_at_a_snapshot():
    newest_first = [
        message("INCREMENTAL", stream_set(3.0, poses={"/pose": {"v": 3}})),
        message("INCREMENTAL", stream_set(2.0, poses={"/pose": {"v": 2}}, primitives={"/obj": {"v": 2}})),
        message(
            "SNAPSHOT",
            stream_set(
                1.0, poses={"/pose": {"v": 1}}, primitives={"/obj": {"v": 1}, "/pts": {"v": 1}}, time_series=SERIES
            ),
        ),
        message("SNAPSHOT", stream_set(0.0, primitives={"/old": {"v": 0}})),
    ]
    state, reached = complete_state(newest_first)
    assert reached
    data = state["data"]
    assert data["update_type"] == "COMPLETE_STATE"
    update = data["updates"][0]
    assert update["timestamp"] == 3.0
    assert update["poses"] == {"/pose": {"v": 3}}
    assert update["primitives"] == {"/obj": {"v": 2}, "/pts": {"v": 1}}  # nothing from before the snapshot
    assert update["time_series"] == SERIES


def test_complete_state_with_a_filter_and_without_a_snapshot():
    newest_first = [
        message(
            "INCREMENTAL",
            stream_set(2.0, time_series=[{"timestamp": 2.0, "streams": ["/a"], "values": {"doubles": [20.0]}}]),
        ),
        message("INCREMENTAL", stream_set(1.0, time_series=SERIES)),
    ]
    state, reached = complete_state(newest_first, {"/a", "/c"})
    assert not reached
    assert state["data"]["updates"][0]["time_series"] == [
        {"timestamp": 2.0, "streams": ["/a"], "values": {"doubles": [20.0]}},
        {"timestamp": 1.0, "streams": ["/c"], "values": {"doubles": [3.0]}},
    ]
