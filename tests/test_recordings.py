"""Recordings the project did not write: the MCAP conformance suite and sample bags of public robotics repositories,
each opened, converted and served (sources, licences and commits in tests/recordings/README.md)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from xviz_server.datasets.ros import RosBag
from xviz_server.datasets.ros.bag import open_bag
from xviz_server.records import unpack

RECORDINGS = Path(__file__).parent / "recordings"
CONFORMANCE = RECORDINGS / "mcap-conformance"
#: Every message of every file of the suite, as its own JSON descriptions list them: (topic, log time, data in hex).
EXPECTED: dict[str, list[list[object]]] = json.loads((CONFORMANCE / "messages.json").read_text())


def test_the_whole_conformance_suite_is_here():
    assert sorted(path.stem for path in CONFORMANCE.glob("*/*.mcap")) == sorted(EXPECTED)
    assert len(EXPECTED) == 416


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_every_conformance_file_opens_with_its_messages(name: str):
    (path,) = CONFORMANCE.glob(f"*/{name}.mcap")
    bag = open_bag(path)
    found = sorted((topic, int(time)) for topic, info in bag.topics.items() for time in info.times)
    assert found == sorted((str(topic), int(time)) for topic, time, _ in EXPECTED[name])  # type: ignore[call-overload]
    for topic, info in bag.topics.items():
        assert list(info.times) == sorted(info.times)  # in time order whatever the file's order
        # The suite's channels have made-up encodings: named per channel, not a refusal of the file.
        assert bag.problems[topic].startswith("no decoder for message encoding ")
    if not found:
        return
    log = RosBag(path)
    assert log.metadata()["streams"].keys() == {"/vehicle_pose"}
    assert log.convert(0)["updates"][0]["poses"]["/vehicle_pose"]["position"] == [0.0, 0.0, 0.0]
    # Every message reaches Foxglove clients as the file holds it, once; but a channel without a schema, which the
    # Foxglove protocol cannot advertise.
    served = [(time, bytes(payload).hex()) for frame in range(len(log)) for _, time, payload in unpack(log.original_messages(frame))]
    schemaless = name.startswith("OneSchemalessMessage")
    assert sorted(served) == [] if schemaless else sorted((int(t), str(data)) for _, t, data in EXPECTED[name])  # type: ignore[call-overload]
