"""`xviz-server validate`: files and log directories against the schema and the layout."""

from __future__ import annotations

import json
from pathlib import Path

from helpers import ten_hz, update, write_log
from xviz_server.codec import Format, encode
from xviz_server.validate import check_paths


def by_name(report) -> dict[str, object]:
    return {f.path.name: f for f in report.files}


def test_real_log_and_golden_files(kitti_log: Path, shared_dir: Path):
    report = check_paths([kitti_log])
    assert report.ok and len(report.files) == 27  # metadata, 25 frames, index
    golden = check_paths([shared_dir / "conformance" / "fixtures" / "minimal-metadata.glb"])
    assert not golden.ok
    assert golden.files[0].problems == ["$.data: 'version' is a required property"]


def test_layout_problems_are_named(tmp_path: Path):
    log = write_log(tmp_path / "log", ten_hz(4), fmt=Format.JSON)
    (log / "3-frame.json").write_bytes(encode({"type": "xviz/metadata", "data": {"version": "2.0.0"}}, Format.JSON))
    (log / "4-frame.json").write_text('{"type": "xviz/state_update"')
    index = json.loads((log / "0-frame.json").read_text())
    index["timing"][3][1] += 5  # wrong span for 5-frame
    index["timing"].append([200.0, 200.0, 9, "11-frame"])  # a frame that does not exist
    (log / "0-frame.json").write_text(json.dumps(index))
    files = by_name(check_paths([log]))
    assert files["1-frame.json"].ok
    assert files["3-frame.json"].problems == ["holds 'xviz/metadata' where the log layout needs 'xviz/state_update'"]
    assert "invalid JSON" in files["4-frame.json"].problems[0]
    assert files["0-frame.json"].problems == [
        "names frames with no file: 11-frame",
        "frame 3 (5-frame) spans 100.3-100.3, the index says 100.3-105.3",
    ]


def test_undeclared_streams_and_missing_index_are_warnings(tmp_path: Path):
    log = write_log(
        tmp_path / "log",
        [update(1.0, streams=("/vehicle_pose", "/points"))],
        index=False,
        meta={"version": "2.0.0", "streams": {"/vehicle_pose": {"category": "POSE"}}},
    )
    report = check_paths([log])
    assert report.ok
    files = by_name(report)
    assert files["2-frame.glb"].warnings == ["streams not declared in the metadata: /points"]
    assert files["0-frame.json"].warnings == ["no index: servers must read every frame to build one"]


def test_schema_violations_and_missing_paths(tmp_path: Path):
    bad = tmp_path / "bad.json"
    bad.write_text(
        json.dumps(
            {
                "type": "xviz/state_update",
                "data": {"update_type": "SNAPSHOT", "updates": [{"timestamp": "now", "poses": {}}]},
            }
        )
    )
    report = check_paths([bad, tmp_path / "missing.glb", tmp_path])
    files = report.files
    assert files[0].problems == ["$.data.updates[0].timestamp: 'now' is not of type 'number'"]
    assert files[1].problems == ["no such file or directory"]
    assert "no XVIZ log" in files[2].problems[0]
    assert not report.ok
    text = report.render()
    assert "bad.json  INVALID  xviz/state_update" in text and text.endswith(
        "3 files checked: 0 ok, 3 invalid, 0 warnings"
    )


def test_validate_command_exit_status_and_json(kitti_log: Path, shared_dir: Path, capsys):
    from xviz_server.cli import main

    assert main(["validate", str(kitti_log)]) == 0
    assert capsys.readouterr().out.strip().endswith("27 files checked: 27 ok, 0 invalid, 0 warnings")
    golden = shared_dir / "conformance" / "fixtures" / "minimal-state-update.glb"
    assert main(["validate", "--json", str(golden)]) == 1
    report = json.loads(capsys.readouterr().out)
    assert report["ok"] is False and report["files"][0]["type"] == "xviz/state_update"
    assert "$.data: 'update_type' is a required property" in report["files"][0]["problems"]
