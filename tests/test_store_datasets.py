"""Datasets in an object store (issue 14): bags, Waymo segments and KITTI drives served from moto's real S3 API.

The KITTI excerpt as a raw drive, written as a ROS 1 bag and as an MCAP
file, and a generated Waymo segment, are uploaded to the store and also kept
on disk: the frames served from the store must be the bytes served from the
files. A proxy (devkit/tcpproxy.py) between the server and the store counts
the GETs, answers 404 and cuts connections.
"""

from __future__ import annotations

import asyncio
import logging
import pickle
import random
import re
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import quote

import pytest

from devkit.rosbag_kitti import CLOUD_TOPIC, RAW, write_bag
from devkit.s3 import SECRET_KEY, MotoS3, moto_process, proxied, store_env
from devkit.tcpproxy import Proxy
from devkit.waymo_scene import write_scene
from helpers import client, run_xviz_session_async, running_server
from xviz_server.codec import Format
from xviz_server.datasets.kitti import KittiDrive
from xviz_server.exceptions import StoreError
from xviz_server.store.client import store_config
from xviz_server.store.path import CACHE_BYTES, MIN_FETCH, StorePath

#: Datasets converted from moto's S3 server: each test several seconds on 2 cores.
pytestmark = pytest.mark.slow

BUCKET = "xviz-data"
ROOT = f"s3://{BUCKET}/fleet"
BAG_FRAMES = 8
WAYMO_FRAMES = 3
KITTI_DRIVE = "kitti-raw/2011_09_26/2011_09_26_drive_0001_sync"
#: Each dataset: its key below the prefix (a folder's for KITTI), its log name, its frame count.
DATASETS = {
    "ros1": ("bags/ros1/drive.bag", "bags/ros1/drive", BAG_FRAMES),
    "mcap": ("bags/mcap/drive.mcap", "bags/mcap/drive", BAG_FRAMES),
    "waymo": ("waymo/segment-15.tfrecord", "waymo/segment-15", WAYMO_FRAMES),
    "kitti": (KITTI_DRIVE, KITTI_DRIVE, 25),
}


@pytest.fixture(scope="module")
def files(shared_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The datasets on disk, laid out as in the store, and a ROS 2 sqlite3 bag."""
    root = tmp_path_factory.mktemp("datasets")
    drive = KittiDrive(shared_dir / "data" / RAW)
    for container in ("ros1", "mcap"):
        key = DATASETS[container][0]
        (root / key).parent.mkdir(parents=True)
        write_bag(root / key, container, drive=drive, frames=BAG_FRAMES)
    tfrecord, npz, _ = write_scene(tmp_path_factory.mktemp("scene"), frames=WAYMO_FRAMES)
    (root / "waymo").mkdir()
    shutil.copy(tfrecord, root / DATASETS["waymo"][0])
    write_bag(root / "bags" / "sqlite3" / "drive", "sqlite3", drive=drive, frames=2)
    return root


@pytest.fixture(scope="module")
def s3(files: Path, shared_dir: Path) -> Iterator[MotoS3]:
    with moto_process() as store:
        store.bucket(BUCKET)
        store.upload(files, BUCKET, "fleet")
        store.upload(shared_dir / "data" / RAW / "2011_09_26", BUCKET, "fleet/kitti-raw/2011_09_26")
        yield store


def on_disk(container: str, files: Path, shared_dir: Path, root: Path) -> Path:
    """A data directory holding the dataset of ``container`` under the name it has in the store."""
    key = DATASETS[container][0]
    if container == "kitti":
        root.mkdir()
        (root / "kitti-raw").symlink_to(shared_dir / "data" / RAW)
    else:
        (root / key).parent.mkdir(parents=True)
        shutil.copy(files / key, root / key)
    return root


@pytest.fixture
async def proxy(s3: MotoS3, monkeypatch: pytest.MonkeyPatch) -> Any:
    async with proxied(s3, monkeypatch) as running:
        yield running


async def stream(server: Any, log: str) -> list[dict[str, Any]]:
    async with client(server, f"/?log={log}") as viewer:
        assert (await viewer.recv())["type"] == "xviz/metadata"
        await viewer.send("transform_log", {"id": "all"})
        return await viewer.until("transform_log_done", "all")


def updates(messages: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [m for m in messages if m["type"] == "xviz/state_update"]


async def frames(server: Any, name: str) -> list[bytes]:
    log = await server.shelf.open(name)
    return [await log.frame(number, Format.BINARY) for number in range(len(log.index))]


async def test_datasets_in_the_store_are_listed_beside_logs_and_a_sqlite3_bag_is_refused_with_a_warning(
    proxy: Proxy, files: Path, caplog: pytest.LogCaptureFixture
):
    async with running_server([ROOT]) as server:
        assert server.shelf.names() == sorted(name for _, name, _ in DATASETS.values())
    refused = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING and "drive.db3" in r.getMessage()]
    assert (
        len(refused) == 1
        and "SQLite" in refused[0]
        and f"s3://{BUCKET}/fleet/bags/sqlite3/drive/drive.db3" in refused[0]
    )


@pytest.mark.parametrize("container", DATASETS)
async def test_frames_from_the_store_are_the_bytes_from_the_same_files_on_disk(
    container: str, proxy: Proxy, files: Path, shared_dir: Path, tmp_path: Path
):
    key, name, count = DATASETS[container]
    local = on_disk(container, files, shared_dir, tmp_path / "local")
    async with running_server([ROOT]) as from_store, running_server([local]) as from_disk:
        stored, read = await frames(from_store, name), await frames(from_disk, name)
        messages = await stream(from_store, name)
        assert (await from_store.shelf.open(name)).metadata == (await from_disk.shelf.open(name)).metadata
    assert len(stored) == count and stored == read
    assert len(updates(messages)) == count and not [m for m in messages if m["type"] == "xviz/error"]
    if container != "kitti":  # a KITTI drive's files are objects of their own, read whole
        heads = [h.lower() for h in proxy.heads if h.startswith(b"GET ") and key.encode() in h.split(b"\r\n")[0]]
        assert heads and all(b"\r\nrange: bytes=" in h for h in heads)  # never the whole object


async def test_the_published_client_reads_a_bag_from_the_store(proxy: Proxy, shared_dir: Path):
    name = DATASETS["mcap"][1]
    script = [
        {"wait": "metadata"},
        {"send_transform_log": {"id": "0", "from_start": -1}},
        {"wait": "done", "id": "0"},
        {"close": True},
    ]
    drive = KittiDrive(shared_dir / "data" / RAW)
    async with running_server([ROOT]) as server:
        url = f"ws://127.0.0.1:{server.port}/?log={name}&worker=true&profile=default&message_format=BINARY"
        result = await run_xviz_session_async(url, script, timeout=180)
    assert result.ok, result.stderr
    assert result.summary is not None and result.summary["errors"] == []
    received = [u["parsed"] for u in result.of_type("xviz/state_update")]
    assert [u["timestamp"] for u in received] == pytest.approx(list(drive.times[:BAG_FRAMES]))
    sweeps = [drive.velodyne(i) for i in range(BAG_FRAMES)]
    assert [u["streams"][CLOUD_TOPIC]["pointCloud"]["numInstances"] for u in received] == [len(s) for s in sweeps]


@pytest.mark.parametrize("container", ["ros1", "waymo", "kitti"])
async def test_a_404_mid_stream_is_an_error_naming_log_frame_and_key_and_the_rest_is_served(
    container: str, proxy: Proxy
):
    key, name, count = DATASETS[container]
    if container == "kitti":
        key += "/velodyne_points/data/0000000003.bin"
    async with running_server([ROOT]) as server:
        await server.shelf.open(name)
        injected = proxy.fault(key, status=404, times=1)  # not retried: exactly one GET fails
        first = await stream(server, name)
        again = await stream(server, name)
    errors = [m["data"]["message"] for m in first if m["type"] == "xviz/error"]
    assert len(errors) == 1 and len(updates(first)) == count - 1, errors
    assert f"of log {name!r}" in errors[0] and f"s3://{BUCKET}/fleet/{key}: no such object (404)" in errors[0], errors[
        0
    ]
    assert injected.hits == 1 and re.search(rf"frame \d+ of log {re.escape(repr(name))}: s3://", errors[0]), errors[0]
    assert len(updates(again)) == count and not [m for m in again if m["type"] == "xviz/error"]  # the failed frame too


@pytest.mark.parametrize("container", ["mcap", "waymo"])
async def test_connections_cut_while_streaming_are_errors_and_the_server_serves_on(container: str, proxy: Proxy):
    key, name, count = DATASETS[container]
    async with running_server([ROOT], store_retries=1) as server:
        await server.shelf.open(name)
        proxy.fault(key, cut_after=100)  # every try cut short
        cut = await stream(server, name)
        proxy.faults.clear()
        again = await stream(server, name)
    errors = [m["data"]["message"] for m in cut if m["type"] == "xviz/error"]
    # A bag's chunks read when it was opened (in a worker process) may still be in that worker's cache: those frames
    # are served; every other frame is an error.
    assert len(errors) + len(updates(cut)) == count and (container == "mcap" or not updates(cut))
    for error in errors:
        assert f"of log {name!r}" in error and f"s3://{BUCKET}/fleet/{key}" in error, error
        assert "the connection failed or was cut short" in error, error
    assert len(updates(again)) == count and not [m for m in again if m["type"] == "xviz/error"]


async def test_an_object_that_is_gone_when_opened_is_an_error_naming_it(proxy: Proxy, s3: MotoS3, files: Path):
    s3.put(BUCKET, "gone/x.tfrecord", (files / DATASETS["waymo"][0]).read_bytes())
    async with running_server([f"s3://{BUCKET}/gone"]) as server:
        assert server.shelf.names() == ["x"]
        s3.delete(BUCKET, "gone/x.tfrecord")
        async with client(server, "/?log=x") as viewer:
            error = await viewer.recv()
    assert error["type"] == "xviz/error"
    assert f"s3://{BUCKET}/gone/x.tfrecord: no such object (404)" in error["data"]["message"], error


async def test_a_dataset_uploaded_while_serving_is_found_on_first_request(proxy: Proxy, s3: MotoS3, files: Path):
    async with running_server([f"s3://{BUCKET}/late"]) as server:
        assert server.shelf.names() == []
        s3.put(BUCKET, "late/more/drive.mcap", (files / DATASETS["mcap"][0]).read_bytes())
        assert len(updates(await stream(server, "more/drive"))) == BAG_FRAMES


async def test_a_kitti_drive_uploaded_while_serving_is_found_on_first_request_as_on_disk(
    proxy: Proxy, s3: MotoS3, files: Path, shared_dir: Path, tmp_path: Path
):
    name = DATASETS["kitti"][1]
    local = on_disk("kitti", files, shared_dir, tmp_path / "local")
    async with running_server([f"s3://{BUCKET}/late-kitti"]) as from_store, running_server([local]) as from_disk:
        assert from_store.shelf.names() == []
        await asyncio.to_thread(
            s3.upload, shared_dir / "data" / RAW / "2011_09_26", BUCKET, "late-kitti/kitti-raw/2011_09_26"
        )
        started = len(proxy.requests)
        messages = await stream(from_store, name)  # the first request that names it
        lookup = [r for r in proxy.requests[started:] if "list-type" in r]
        stored, read = await frames(from_store, name), await frames(from_disk, name)
        assert (await from_store.shelf.open(name)).metadata == (await from_disk.shelf.open(name)).metadata
        await from_store.indexer.settled()  # the catalog lists what the session found, before the store's next listing
        assert from_store.shelf.names() == [name]
    assert len(updates(messages)) == 25 and not [m for m in messages if m["type"] == "xviz/error"]
    assert stored == read and len(stored) == 25
    # the drive's folder, the date folder, then everything below the drive: never the whole prefix
    assert len(lookup) == 3 and all("prefix=late-kitti%2Fkitti-raw%2F2011_09_26%2F" in r for r in lookup), lookup


@pytest.mark.parametrize(
    ("unknown", "listings"), [("kitti-raw/2011_09_26/drive_9", 2), ("kitti-raw/2011_09_26", 3), ("nothing", 2)]
)
async def test_an_unknown_name_is_not_found_after_at_most_one_listing_of_the_named_folder(
    unknown: str, listings: int, proxy: Proxy, s3: MotoS3, shared_dir: Path
):
    async with running_server([f"s3://{BUCKET}/unknown"]) as server:
        await asyncio.to_thread(
            s3.upload, shared_dir / "data" / RAW / "2011_09_26", BUCKET, "unknown/kitti-raw/2011_09_26"
        )
        started = len(proxy.requests)
        async with client(server, f"/?log={unknown}") as viewer:
            error = await viewer.recv()
        lookup = [r for r in proxy.requests[started:] if "list-type" in r]
    assert error["type"] == "xviz/error" and f"no log named {unknown!r}" in error["data"]["message"], error
    whole = [r for r in lookup if "delimiter=" not in r]  # listings of everything below a folder
    assert len(lookup) == listings and all(
        r.endswith(f"prefix={quote(f'unknown/{unknown}/', safe='')}") for r in whole
    ), lookup


async def test_a_store_path_pickles_shows_no_credential_and_reads_ranges_through_a_bounded_cache(
    proxy: Proxy, files: Path
):
    key = DATASETS["ros1"][0]
    data = (files / key).read_bytes()
    path = StorePath(store_config(BUCKET, timeout=10, retries=0), f"fleet/{key}", len(data))
    assert str(path) == f"s3://{BUCKET}/fleet/{key}" and repr(path) == f"StorePath('s3://{BUCKET}/fleet/{key}')"
    assert SECRET_KEY not in repr(path.config) and SECRET_KEY not in str(path)
    copy = pickle.loads(pickle.dumps(path))  # as the workers get it
    middle = len(data) // 2

    def reads() -> list[bytes]:  # requests block: in a thread, as the server makes them
        with copy.open() as file:
            got = [file.read(13), file.read(100)]
            file.seek(-37, 2)
            got += [file.read(), file.read(1)]
            file.seek(middle)
            got.append(file.read(2 * CACHE_BYTES))
            file.prefetch([(0, 10), (1000, 2000)])
            return got

    got = await asyncio.to_thread(reads)
    assert got == [data[:13], data[13:113], data[-37:], b"", data[middle : middle + 2 * CACHE_BYTES]]
    assert (
        len(data) > 2 * MIN_FETCH and len(proxy.gets(key)) == 3
    )  # the start (the 100 bytes held), the end, the middle
    proxy.fault(key, status=403)
    with pytest.raises(StoreError, match=f"s3://{BUCKET}/fleet/{key}: access denied \\(403\\)"):
        await asyncio.to_thread(lambda: copy.open().read(10))


async def test_random_reads_return_the_objects_bytes_and_near_ones_share_a_get(proxy: Proxy, s3: MotoS3):
    rng = random.Random(14)
    data = rng.randbytes(3 << 20)
    s3.put(BUCKET, "random/blob", data)
    path = StorePath(store_config(BUCKET, timeout=10, retries=0), "random/blob", len(data))
    reads = [(rng.randrange(len(data)), rng.choice([1, 12, 300, 5000, 70_000, 1 << 20])) for _ in range(300)]
    reads += [(start + 7, 100) for start, _ in reads[:100]]  # each within what a read before it fetched

    def read_all() -> list[bytes]:
        with path.open() as file:
            return [file.read(size) for start, size in reads if file.seek(start) == start]

    got = await asyncio.to_thread(read_all)
    assert got == [data[start : start + size] for start, size in reads]
    assert len(proxy.gets("random/blob")) <= 300


@pytest.mark.parametrize("container", ["ros1", "mcap", "waymo"])
async def test_answers_that_claim_a_terabyte_and_never_end_cost_no_memory(container: str, proxy: Proxy):
    """Every GET of a recording in the store (its index ranges at once, a chunk, a record) answered with
    Content-Length 1 TiB and zeros without end: each reads the range it asked for and no more, and the recording
    is an error naming it (zeros are not a recording); the other recordings are served, memory stays bounded."""
    from test_bombs import GROWTH, served

    key, name, _ = DATASETS[container]
    other = "bags/mcap/drive" if container != "mcap" else "bags/ros1/drive"
    env = {**store_env(proxy.url), "XVIZ_STORE_RETRIES": "0", "XVIZ_STORE_TIMEOUT": "3"}
    proxy.fault(key, endless=True)
    async with served(ROOT, **env) as server:
        assert updates(await server.session(other))
        before = server.rss()
        bad, good = await asyncio.gather(server.session(name), server.session(other))
        errors = [m["data"]["message"] for m in bad if m["type"] == "xviz/error"]
        assert errors and all(f"log {name!r}" in error for error in errors), errors
        assert len(updates(good)) == BAG_FRAMES and await server.get("/healthz") == (200, "ok\n")
        peaks = server.peaks()
        assert max(peaks[pid] - rss for pid, rss in before.items() if pid in peaks) < GROWTH


async def test_ranges_read_at_once_take_no_more_of_an_endless_answer_than_asked(proxy: Proxy, files: Path):
    key = DATASETS["ros1"][0]
    size = (files / key).stat().st_size
    path = StorePath(store_config(BUCKET, timeout=3.0, retries=0), f"fleet/{key}", size)
    proxy.fault(key, endless=True)
    Path("/proc/self/clear_refs").write_text("5")  # the peak RSS starts again from the RSS now
    before = int(re.search(r"VmHWM:\s+(\d+)", Path("/proc/self/status").read_text())[1]) << 10
    parts = await asyncio.to_thread(path.read_ranges, [(0, 1000), (200_000, 300_000), (250_000, 260_000)])
    peak = int(re.search(r"VmHWM:\s+(\d+)", Path("/proc/self/status").read_text())[1]) << 10
    assert [len(part) for part in parts] == [1000, 100_000, 10_000] and not any(b"".join(parts))
    assert peak - before < 64 << 20, f"{(peak - before) >> 20} MiB"
