"""Where a KITTI raw drive may be given: the drive, its date folder, or the folder above (issue 19, item 4).

Each level is tried on the real excerpt, with ``xviz-server convert`` as the
Docker ``convert`` service runs it and as a dataset the server serves.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from helpers import client, running_server
from xviz_server.datasets.kitti import KittiDrive
from xviz_server.exceptions import DatasetError

DATE = "2011_09_26"
DRIVE = "2011_09_26_drive_0001_sync"


@pytest.fixture(scope="module")
def raw(shared_dir: Path) -> Path:
    return shared_dir / "data" / "kitti-raw-2011_09_26_drive_0001-head"


def linked_copy(source: Path, target: Path) -> Path:
    shutil.copytree(source, target, copy_function=os.symlink)
    return target


@pytest.mark.parametrize("level", ["drive", "date", "above"])
def test_each_level_finds_the_drive_and_its_calibration(raw: Path, level: str):
    path = {"drive": raw / DATE / DRIVE, "date": raw / DATE, "above": raw}[level]
    drive = KittiDrive(path)
    assert drive.path == raw / DATE / DRIVE and drive.name == DRIVE and len(drive) == 25
    assert drive.lidar_transform[12:15] == [0.81, -0.32, 1.73]  # read from the date folder's calibration


@pytest.mark.parametrize("level", ["date", "above"])
def test_convert_takes_each_level(raw: Path, tmp_path: Path, level: str):
    source = raw / DATE if level == "date" else raw
    out = tmp_path / "log"
    result = subprocess.run(
        [sys.executable, "-m", "xviz_server", "convert", "kitti", str(source), str(out), "--frames", "0:2"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    assert sorted(p.name for p in out.iterdir()) == ["0-frame.json", "1-frame.glb", "2-frame.glb", "3-frame.glb"]


async def test_a_date_folder_is_served_as_a_dataset(raw: Path):
    async with running_server(None, dataset=[f"kitti:{raw / DATE}"]) as server:
        async with client(server) as c:
            metadata = await c.recv()
            assert metadata["data"]["log_info"]["start_time"] == 1317042145.964


def test_several_drives_are_listed_to_choose_from(raw: Path, tmp_path: Path):
    date = linked_copy(raw / DATE, tmp_path / "raw" / DATE)
    linked_copy(raw / DATE / DRIVE, date / "2011_09_26_drive_0002_sync")
    drives = [date / DRIVE, date / "2011_09_26_drive_0002_sync"]
    for path in (date, date.parent):
        with pytest.raises(DatasetError) as error:
            KittiDrive(path)
        assert str(error.value) == f"{path}: 2 KITTI drives, give one of them: {drives[0]}, {drives[1]}"
    assert KittiDrive(drives[1]).name == "2011_09_26_drive_0002_sync"  # the drive named, inside its date folder
    result = subprocess.run(
        [sys.executable, "-m", "xviz_server", "convert", "kitti", str(date), str(tmp_path / "out")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 1 and "2 KITTI drives, give one of them" in result.stderr


def test_a_drive_folder_alone_says_to_give_the_date_folder(raw: Path, tmp_path: Path):
    alone = linked_copy(raw / DATE / DRIVE, tmp_path / "mounted" / DRIVE)  # as a bind mount of the drive alone
    with pytest.raises(
        DatasetError,
        match=rf"{tmp_path / 'mounted' / 'calib_imu_to_velo.txt'} not found: KITTI keeps the "
        "calibration files in the date folder above each drive; give \\(or mount\\) the date folder",
    ):
        KittiDrive(alone)
    with pytest.raises(DatasetError, match="not a KITTI raw drive, date folder or folder of dates"):
        KittiDrive(tmp_path / "mounted" / DRIVE / "oxts")
