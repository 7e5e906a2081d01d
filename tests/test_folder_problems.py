"""What is wrong in the data folder or with an option is logged once, at WARNING, with its cause.

Bags and MCAP files are written with rosbags' own writers (devkit.rosbag_kitti),
then broken as files are in the field: not a bag at all, empty, cut short.
"""

from __future__ import annotations

import asyncio
import logging
import subprocess
import sys
import time
from pathlib import Path

import pytest
from rosbags.typesys import Stores

from devkit.rosbag_kitti import Messages, viz_messages, write_bag
from helpers import clean_env, running_server, start_serving, stop_serving
from xviz_server.catalog import parse_query
from xviz_server.server import XVIZServer
from xviz_server.settings import Settings


def mcap(path: Path) -> Path:
    return write_bag(path, "mcap", viz_messages(Messages(Stores.ROS2_HUMBLE)))


def ros1(path: Path) -> Path:
    return write_bag(path, "ros1", viz_messages(Messages(Stores.ROS1_NOETIC)))


def warnings(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [record.getMessage() for record in caplog.records if record.levelno >= logging.WARNING]


async def names(server: XVIZServer) -> list[str]:
    return [log["name"] for log in (await server.indexer.page(parse_query({})))["logs"]]


@pytest.mark.slow
async def test_each_problem_in_the_data_folder_is_logged_once_with_its_cause(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
):
    data = tmp_path / "logs"
    data.mkdir()
    whole = mcap(data / "drive.mcap").read_bytes()
    (data / "cut.mcap").write_bytes(whole[: len(whole) // 2])
    (data / "notes.bag").write_text("these are not the bags you are looking for\n")
    (data / "empty.bag").touch()
    ros1(data / "twin.bag")
    (data / "twin.mcap").write_bytes(whole)
    (data / "readme.txt").write_text("a file of no dataset's suffix is no problem\n")
    caplog.set_level(logging.WARNING, logger="xviz_server")
    async with running_server(data, catalog_poll=0.1) as server:
        # Another file makes the scan look at the folder again; what was logged is not logged twice.
        mcap(data / "later.mcap")
        deadline = time.monotonic() + 30
        while "later" not in await names(server):
            assert time.monotonic() < deadline, "the new file was not listed"
            await asyncio.sleep(0.1)
        listed = await names(server)
    assert sorted(listed) == ["cut", "drive", "later", "twin"]
    assert sorted(warnings(caplog)) == sorted(
        [
            f"{data / 'cut.mcap'}: a truncated MCAP file: it does not end with the MCAP magic (cut short, or still being "
            "written), and opens only once complete; listed all the same",
            f"{data / 'empty.bag'}: left out of the catalog: not a ROS 1 bag: the file is empty",
            f"{data / 'notes.bag'}: left out of the catalog: not a ROS 1 bag: it starts with b'these are not th'",
            f"{data / 'twin.bag'}: twin.mcap has its name, 'twin', and is served under it",
        ]
    )


async def test_a_dataset_option_that_names_another_kind_or_a_truncated_file_is_logged(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
):
    bag = ros1(tmp_path / "x.bag")
    whole = mcap(tmp_path / "whole.mcap").read_bytes()
    (tmp_path / "cut.mcap").write_bytes(whole[:-100])
    caplog.set_level(logging.WARNING, logger="xviz_server")
    settings = Settings(
        host="127.0.0.1",
        port=0,
        dataset=[f"kitti:{bag}", f"rosbag:{tmp_path / 'cut.mcap'}", f"rosbag:{tmp_path / 'whole.mcap'}"],
    )
    async with XVIZServer(settings):
        pass
    assert warnings(caplog) == [
        f"--dataset kitti:{bag}: {bag} is a ROS bag or MCAP file (or a ROS 2 bag folder), not a KITTI raw drive folder "
        f"(or its date folder): give --dataset rosbag:{bag}",
        f"--dataset rosbag:{tmp_path / 'cut.mcap'}: a truncated MCAP file: it does not end with the MCAP magic (cut "
        "short, or still being written), and opens only once complete",
    ]


@pytest.mark.slow
def test_a_data_dir_that_is_a_bag_points_at_the_dataset_option(tmp_path: Path):
    bag = ros1(tmp_path / "my.bag")
    result = subprocess.run(
        [sys.executable, "-m", "xviz_server", "serve", "--data-dir", str(bag)],
        capture_output=True,
        text=True,
        timeout=60,
        env=clean_env(),
    )
    assert result.returncode == 2
    assert result.stderr == (
        f"xviz-server serve: --data-dir {bag} is not a directory: to serve this file alone, give "
        f"--dataset rosbag:{bag} (--data-dir takes the folder that holds it)\n"
    )
    help_text = subprocess.run(
        [sys.executable, "-m", "xviz_server", "serve", "--help"],
        capture_output=True,
        text=True,
        timeout=60,
        env=clean_env(),
    ).stdout
    assert "each log a folder" not in help_text and "ROS bags and" in help_text


@pytest.mark.slow
async def test_a_default_run_logs_no_warning():
    process, port, lines = await start_serving()
    output = await stop_serving(process, lines)
    assert (
        f"listening on ws://127.0.0.1:{port}/\n" in output and f"the viewer page: http://127.0.0.1:{port}/\n" in output
    )
    assert "live ingest (/ingest/NAME) is open to every local process" in output  # said, at INFO
    assert " WARNING " not in output and "Traceback" not in output
