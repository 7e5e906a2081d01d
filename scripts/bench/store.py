#!/usr/bin/env python3
"""Benchmark streaming a log from an object store, against the store's own GET rate, in one run.

    .venv/bin/python scripts/bench/store.py [--trials N] [--delay S] [--json FILE] [--kitti DIR] [--quick]

Every party is its own process: moto's S3 server (``python -m moto.server``)
holding the KITTI excerpt (25 frames, 2.5 s of drive at 10 Hz) as
``s3://xviz-logs/fleet/kitti``; the server under test
(``python -m xviz_server serve --data-dir s3://xviz-logs/fleet``); the client
(``kit.peers``, the "raw" client). Rows:

1. cold: a whole-log stream from a server just started (its log open, no
   frame read yet), against the store's own sequential GET rate measured
   here with obstore, one GET after another, for the same objects, the
   median of as many trials (target: >= 0.8x);
2. the same through a loopback proxy (``devkit.tcpproxy``) that waits
   ``--delay`` (50 ms) before each request: the stream's rate as a multiple
   of real time (target: >= 5x), and against sequential GETs through the
   same proxy;
3. warm: whole-log streams of frames in the cache, from the store-backed log
   and from the same log on disk, each as a ratio to the bare websockets
   server of ``kit.peers`` (target: the same ratio);
4. datasets: a ROS 1 bag and an MCAP file of ``--bag-frames`` generated
   frames (``kit.gen.generate_bag``: a 120 000-point cloud and a 1242x375
   image each), and the KITTI excerpt's raw drive (25 frames), served on
   demand from the store, against the same files served from a directory:
   the open (connect to metadata) and the whole-log stream, each server just
   started, as ratios; and the same through the delaying proxy, with the
   GETs it saw. moto's ranged GET takes longer the larger the object (it
   copies it), unlike S3: each row says how long a 64 KiB one takes there.

Each cold or delayed row is the median of ``--trials`` fresh servers. Speed
is reported as ratios against references measured in the same run; the
machine may be shared, and each row says how many cores other processes
used meanwhile.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import obstore
import websockets
from kit import KITTI, parse
from kit import KITTI_RAW as RAW
from kit.gen import generate_bag as generate
from kit.proc import MB, Process, other_cores, other_cpu, run_clients, start_reference, start_server
from obstore.store import S3Store

from devkit.s3 import ACCESS_KEY, SECRET_KEY, MotoS3, moto_process, store_env
from devkit.tcpproxy import Proxy
from xviz_server.codec import decode

BUCKET = "xviz-logs"
ROOT = f"s3://{BUCKET}/fleet"
DRIVE_SECONDS = 2.5  # 25 frames at 10 Hz


def line(text: str = "") -> None:
    print(text, flush=True)


def sequential_gets(endpoint: str, keys: list[str], trials: int) -> dict[str, float]:
    """The store's own rate: every object GET after GET with obstore, the median of ``trials`` after a warm-up."""

    async def run() -> list[tuple[float, int]]:
        store = S3Store(
            BUCKET,
            endpoint=endpoint,
            client_options={"allow_http": True},
            region="us-east-1",
            access_key_id=ACCESS_KEY,
            secret_access_key=SECRET_KEY,
        )
        await (await obstore.get_async(store, keys[0])).bytes_async()  # the connection, set up
        times = []
        for _ in range(trials):
            size, started = 0, time.perf_counter()
            for key in keys:
                size += len(await (await obstore.get_async(store, key)).bytes_async())
            times.append((time.perf_counter() - started, size))
        return times

    times = asyncio.run(run())
    seconds, size = sorted(times)[len(times) // 2]
    return {"seconds": seconds, "frames_s": len(keys) / seconds, "mb_s": size / MB / seconds}


@contextmanager
def proxy_thread(port: int, delay: float) -> Iterator[Proxy]:
    """The delaying proxy, run on an event loop in a thread of this process."""
    loop = asyncio.new_event_loop()
    proxy = Proxy(port, delay)
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    asyncio.run_coroutine_threadsafe(proxy.start(), loop).result(10)
    try:
        yield proxy
    finally:
        asyncio.run_coroutine_threadsafe(proxy.close(), loop).result(10)
        loop.call_soon_threadsafe(loop.stop)
        thread.join(10)


def cold_stream(endpoint: str, trials: int, extra: tuple[str, ...] = ()) -> dict[str, Any]:
    """Median of ``trials`` whole-log streams, each from a server just started (metadata and index read, no frame)."""
    os.environ.update(store_env(endpoint))
    runs = []
    for _ in range(trials):
        with start_server(ROOT, *extra) as server:
            runs.append(
                run_clients(
                    {"task": "stream", "url": server.url("?log=kitti"), "clients": 1, "repeats": 1}, 1, server.pid
                )
            )
    assert all(run["frames"] == 25 and run["errors"] == 0 for run in runs), runs
    middle = sorted(runs, key=lambda run: run["seconds"])[len(runs) // 2]
    return {**middle, "all_seconds": [run["seconds"] for run in runs]}


def warm_stream(server: Process, name: str, repeats: int) -> dict[str, Any]:
    url = server.url(f"?log={name}")
    run_clients({"task": "stream", "url": url, "clients": 1, "repeats": 1})  # fills the cache
    return run_clients({"task": "stream", "url": url, "clients": 1, "repeats": repeats}, 1, server.pid)


async def timed_stream(url: str) -> dict[str, float]:
    """Seconds from connecting to the metadata (the log opened), and from asking for the whole log to its done."""
    started = time.perf_counter()
    async with websockets.connect(url, max_size=None) as websocket:
        assert decode(await websocket.recv())["type"] == "xviz/metadata"
        opened = time.perf_counter()
        await websocket.send(json.dumps({"type": "xviz/transform_log", "data": {"id": "1"}}))
        frames = 0
        while True:
            message = decode(await websocket.recv())
            if message["type"] == "xviz/transform_log_done":
                break
            assert message["type"] == "xviz/state_update", message
            frames += 1
    return {"open_s": opened - started, "stream_s": time.perf_counter() - opened, "frames": frames}


def ranged_get_ms(s3: MotoS3, key: str, trials: int = 10) -> float:
    """Median ms of a 64 KiB ranged GET of ``key`` with obstore: moto's own cost, which grows with the object's size."""
    store = S3Store(
        BUCKET,
        endpoint=s3.endpoint,
        client_options={"allow_http": True},
        region="us-east-1",
        access_key_id=ACCESS_KEY,
        secret_access_key=SECRET_KEY,
    )
    times = []
    for trial in range(trials + 1):
        started = time.perf_counter()
        obstore.get_range(store, key, start=trial << 16, length=1 << 16)
        times.append(time.perf_counter() - started)
    return sorted(times[1:])[trials // 2] * 1000


def datasets(s3: MotoS3, frames: int, delay: float, extra: tuple[str, ...]) -> dict[str, Any]:
    """Row 4: each bag from the store, from a directory, and from the store through the delaying proxy."""
    results: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as folder:
        local = Path(folder) / "bags"
        local.mkdir()
        for container, file in (("ros1", "drive.bag"), ("mcap", "drive.mcap")):
            path = local / file
            if container == "mcap":  # rosbags writes MCAP as a ROS 2 bag folder: its one storage file
                generate(local / "drive", container, frames)
                (local / "drive" / "drive.mcap").rename(path)
                for rest in (local / "drive").iterdir():
                    rest.unlink()
                (local / "drive").rmdir()
            else:
                generate(path, container, frames)
            s3.put(BUCKET, f"datasets/{container}/{file}", path.read_bytes())
            row = compare(s3, local, f"datasets/{container}", "drive", delay, extra, f"datasets/{container}/{file}")
            row["megabytes"] = path.stat().st_size / MB
            path.unlink()
            assert row["local"]["frames"] == row["store"]["frames"] == row["delayed"]["frames"] == frames, row
            results[container] = row
    s3.upload(RAW / "2011_09_26", BUCKET, "datasets/kitti/2011_09_26")
    drive = "2011_09_26/2011_09_26_drive_0001_sync"
    velodyne = f"datasets/kitti/{drive}/velodyne_points/data/0000000000.bin"
    row = compare(s3, RAW, "datasets/kitti", drive, delay, extra, velodyne, gets="datasets/kitti/")
    row["megabytes"] = sum(p.stat().st_size for p in RAW.rglob("*") if p.is_file()) / MB
    assert row["local"]["frames"] == row["store"]["frames"] == row["delayed"]["frames"] == 25, row
    results["kitti"] = row
    return results


def compare(
    s3: MotoS3,
    local: Path,
    prefix: str,
    name: str,
    delay: float,
    extra: tuple[str, ...],
    probe: str,
    gets: str | None = None,
) -> dict[str, Any]:
    """The log ``name`` from the directory ``local``, from ``s3://BUCKET/prefix``, and from there through the proxy."""
    row: dict[str, Any] = {"ranged_get_ms": ranged_get_ms(s3, probe)}
    os.environ.update(store_env(s3.endpoint))
    with start_server(local, *extra) as server:
        row["local"] = asyncio.run(timed_stream(server.url(f"?log={name}")))
    with start_server(f"s3://{BUCKET}/{prefix}", *extra) as server:
        row["store"] = asyncio.run(timed_stream(server.url(f"?log={name}")))
    with proxy_thread(s3.port, delay) as proxy:
        os.environ.update(store_env(proxy.url))
        with start_server(f"s3://{BUCKET}/{prefix}", *extra) as server:
            row["delayed"] = {
                **asyncio.run(timed_stream(server.url(f"?log={name}"))),
                "gets": len(proxy.gets(gets or probe)),
            }
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--kitti", type=Path, default=KITTI, help=f"the KITTI GLB log (default {KITTI})")
    parser.add_argument("--trials", type=int, default=5, help="fresh servers per cold row (median shown)")
    parser.add_argument("--delay", type=float, default=0.05, help="seconds the proxy waits before each request")
    parser.add_argument("--repeats", type=int, default=20, help="whole-log streams per warm row")
    parser.add_argument(
        "--read-ahead", type=int, help="--store-read-ahead of the servers (default: the server's default)"
    )
    parser.add_argument(
        "--read-ahead-mb", type=float, help="--store-read-ahead-mb of the servers (default: the server's default)"
    )
    parser.add_argument("--bag-frames", type=int, default=30, help="frames of each generated bag of row 4")
    parser.add_argument("--datasets-only", action="store_true", help="only row 4")
    parser.add_argument("--json", type=Path, help="also write the numbers to this file")
    args = parse(parser, quick={"trials": 1, "repeats": 1, "bag_frames": 3, "delay": 0.005})
    extra = (
        *(("--store-read-ahead", str(args.read_ahead)) if args.read_ahead else ()),
        *(("--store-read-ahead-mb", str(args.read_ahead_mb)) if args.read_ahead_mb else ()),
    )
    results: dict[str, Any] = {"load_average_at_start": os.getloadavg(), "server_options": extra}
    line(
        f"object store benchmark, {time.strftime('%Y-%m-%d %H:%M:%S')}; load average at start "
        + " ".join(f"{x:.2f}" for x in os.getloadavg())
        + (f"; server options {' '.join(extra)}" if extra else "")
    )
    with moto_process() as s3:
        s3.bucket(BUCKET)
        keys = [
            key
            for key in s3.upload(args.kitti, BUCKET, "fleet/kitti")
            if key.rsplit("/", 1)[1] not in ("0-frame.json", "1-frame.glb")
        ]
        keys.sort(key=lambda key: int(key.rsplit("/", 1)[1].split("-")[0]))
        line(f"store: moto {MotoS3.__module__} server at {s3.endpoint}, {len(keys)} frames uploaded")

        if not args.datasets_only:
            other_before, wall_before = other_cpu(), time.perf_counter()
            direct = sequential_gets(s3.endpoint, keys, args.trials)
            cold = cold_stream(s3.endpoint, args.trials, extra)
            ratio = cold["frames_s"] / direct["frames_s"]
            results["cold"] = {
                "sequential_gets": direct,
                "stream": cold,
                "ratio": ratio,
                "other_cpu": other_cores(other_before, wall_before),
            }
            line(
                f"1. cold whole-log stream from the store: {cold['frames_s']:.1f} frames/s ({cold['mb_s']:.0f} MB/s), "
                f"sequential GETs {direct['frames_s']:.1f} frames/s ({direct['mb_s']:.0f} MB/s): {ratio:.2f}x (target >= 0.8); "
                f"other processes {results['cold']['other_cpu']:.2f} cores"
            )

            with proxy_thread(s3.port, args.delay) as proxy:
                other_before, wall_before = other_cpu(), time.perf_counter()
                slow_direct = sequential_gets(proxy.url, keys, 1)
                proxy.most_in_flight = 0
                slow = cold_stream(proxy.url, args.trials, extra)
                realtime = DRIVE_SECONDS / slow["seconds"]
                results["delayed"] = {
                    "delay_s": args.delay,
                    "sequential_gets": slow_direct,
                    "stream": slow,
                    "real_time": realtime,
                    "ratio": slow["frames_s"] / slow_direct["frames_s"],
                    "most_in_flight": proxy.most_in_flight,
                    "other_cpu": other_cores(other_before, wall_before),
                }
                line(
                    f"2. with {args.delay * 1000:.0f} ms before each request: {slow['frames_s']:.1f} frames/s, "
                    f"{realtime:.1f}x real time (target >= 5x); sequential GETs {slow_direct['frames_s']:.1f} frames/s "
                    f"({results['delayed']['ratio']:.1f}x); most GETs in flight {proxy.most_in_flight}; "
                    f"other processes {results['delayed']['other_cpu']:.2f} cores"
                )

            os.environ.update(store_env(s3.endpoint))
            with (
                start_server(ROOT, *extra) as store_server,
                start_server(args.kitti.parent) as local_server,
                start_reference({"kitti": args.kitti}) as reference,
            ):
                other_before, wall_before = other_cpu(), time.perf_counter()
                bare = warm_stream(reference, "kitti", args.repeats)
                from_store = warm_stream(store_server, "kitti", args.repeats)
                local = warm_stream(local_server, args.kitti.name, args.repeats)
                results["warm"] = {
                    "bare": bare,
                    "store": from_store,
                    "local": local,
                    "store_ratio": from_store["mb_s"] / bare["mb_s"],
                    "local_ratio": local["mb_s"] / bare["mb_s"],
                    "other_cpu": other_cores(other_before, wall_before),
                }
                line(
                    f"3. warm whole-log streams, {args.repeats} in a row: store-backed {from_store['mb_s']:.0f} MB/s "
                    f"({results['warm']['store_ratio']:.2f}x the bare server), local {local['mb_s']:.0f} MB/s "
                    f"({results['warm']['local_ratio']:.2f}x), bare websockets {bare['mb_s']:.0f} MB/s; "
                    f"other processes {results['warm']['other_cpu']:.2f} cores"
                )

        other_before, wall_before = other_cpu(), time.perf_counter()
        results["datasets"] = datasets(s3, args.bag_frames, args.delay, extra)
        results["datasets"]["other_cpu"] = other_cores(other_before, wall_before)
        for container in ("ros1", "mcap", "kitti"):
            row = results["datasets"][container]
            local, store, delayed = row["local"], row["store"], row["delayed"]
            what = (
                "KITTI raw drive, 25 frames" if container == "kitti" else f"{container} bag, {args.bag_frames} frames"
            )
            line(
                f"4. {what}, {row['megabytes']:.0f} MB, on demand: open "
                f"{store['open_s']:.2f} s from the store, {local['open_s']:.2f} s from a directory "
                f"({store['open_s'] / local['open_s']:.2f}x); whole-log stream {store['stream_s']:.2f} s against "
                f"{local['stream_s']:.2f} s ({store['stream_s'] / local['stream_s']:.2f}x); with {args.delay * 1000:.0f} ms "
                f"before each request: open {delayed['open_s']:.2f} s, stream {delayed['stream_s']:.2f} s, {delayed['gets']} GETs "
                f"(every process of the server); moto takes {row['ranged_get_ms']:.0f} ms for a 64 KiB ranged GET of "
                + ("a sweep" if container == "kitti" else "this object")
            )
        line(f"   other processes {results['datasets']['other_cpu']:.2f} cores")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2, default=str))


if __name__ == "__main__":
    main()
