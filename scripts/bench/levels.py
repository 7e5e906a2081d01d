#!/usr/bin/env python3
"""CPU time of making each level of detail of the real KITTI frames, where the server makes it.

    python scripts/bench/levels.py [--repeat N] [--quick]

Each level of each of the KITTI frames (2.15 MB: 121 000 lidar points and
four PNG camera images) is made by ``frames.render``, as a log session
asks for it, in a worker process of the server's own pool
(``xviz_server.work.Workers``); the CPU time of one making
(``time.process_time``) is the least of ``--repeat`` runs, so that other
processes' load counts as little as it can. Reported per level: the median
frame and the costliest frame, in ms, and the bytes made.

The reference, in the same worker and run: the same level made by the bare
libraries, the way a first version would: decoding the GLB frame, thinning
the cloud by ``np.unique`` of the points' cube keys, Pillow decoding each
image, resizing it (bilinear) when the level shrinks images, and encoding it
as JPEG, and encoding the GLB frame again. Its image part alone is also
shown: Pillow's PNG decode, resize and JPEG encode of the four images.
"""

from __future__ import annotations

import argparse
import asyncio
import io
import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np
from kit import KITTI, parse

from xviz_server import frames
from xviz_server.codec import Format, decode, encode
from xviz_server.levels import LEVELS, Level
from xviz_server.work import Workers

CAMERAS = ["/camera/image_00", "/camera/image_01", "/camera/image_02", "/camera/image_03"]


def bare_images(message: dict[str, Any], level: Level) -> list[bytes]:
    """The level's camera images made by Pillow alone (its PNG decoder, a bilinear resize, its JPEG encoder)."""
    from PIL import Image

    primitives = message["data"]["updates"][0]["primitives"]
    made = []
    for name in CAMERAS:
        picture = Image.open(io.BytesIO(primitives[name]["images"][0]["data"])).convert("RGB")
        if level.image_reduce != 1:
            size = (-(-picture.width // level.image_reduce), -(-picture.height // level.image_reduce))
            picture = picture.resize(size, Image.Resampling.BILINEAR)
        out = io.BytesIO()
        picture.save(out, "JPEG", quality=level.image_quality)
        made.append(out.getvalue())
    return made


def bare_level(data: bytes, level: Level) -> bytes:
    """``level`` of a frame made by the bare libraries: numpy's ``unique`` thins, Pillow re-encodes."""
    assert level.voxel is not None
    message = decode(data)
    primitives = message["data"]["updates"][0]["primitives"]
    cloud = primitives["/lidar/points"]["points"][0]
    cells = np.floor(cloud["points"] / np.float32(level.voxel)).astype(np.int64) + (1 << 20)
    _, keep = np.unique((cells[:, 0] << 42) | (cells[:, 1] << 21) | cells[:, 2], return_index=True)
    cloud["points"], cloud["colors"] = cloud["points"][keep], cloud["colors"][keep]
    for name, image in zip(CAMERAS, bare_images(message, level)):
        primitives[name]["images"][0]["data"] = image
    return encode(message, Format.BINARY)


def cpu_ms(function: Any, *args: Any, repeat: int) -> tuple[float, Any]:
    """The least CPU time of ``function(*args)`` over ``repeat`` runs, in ms, and what it returned."""
    best, result = float("inf"), None
    for _ in range(repeat):
        started = time.process_time()
        result = function(*args)
        best = min(best, time.process_time() - started)
    return best * 1e3, result


def measure(paths: list[Path], repeat: int) -> list[dict[str, Any]]:
    """For each level below full detail: CPU ms of each frame's making, ours and the bare libraries'. Runs in a worker."""
    datas = [path.read_bytes() for path in paths]
    frames.render(datas[0], Format.BINARY, None, None, LEVELS[1])  # imports and first allocations
    rows = []
    for level in LEVELS[1:]:
        if level.every != 1:  # the same making as a level above, sent less often
            continue
        ours, bare, images, sizes = [], [], [], []
        for data in datas:
            ms, made = cpu_ms(frames.render, data, Format.BINARY, None, None, level, repeat=repeat)
            ours.append(ms)
            sizes.append(len(made))
            bare.append(cpu_ms(bare_level, data, level, repeat=repeat)[0])
            images.append(cpu_ms(bare_images, decode(data), level, repeat=repeat)[0])
        rows.append(
            {
                "level": level.name,
                "median": statistics.median(ours),
                "largest": max(ours),
                "bare": statistics.median(bare),
                "bare_images": statistics.median(images),
                "share": statistics.median(sizes) / statistics.median(map(len, datas)),
            }
        )
    return rows


async def run(paths: list[Path], repeat: int) -> list[dict[str, Any]]:
    workers = Workers(processes=1)
    try:
        await workers.warm()
        return await workers.cpu(measure, paths, repeat)
    finally:
        workers.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeat", type=int, default=5, help="runs of each making; the least CPU time counts")
    parser.add_argument("--frames", type=int, default=25, help="how many of the KITTI log's frames")
    args = parse(parser, quick={"repeat": 1, "frames": 2})

    updates = [path for path in KITTI.glob("*-frame.glb") if decode(path.read_bytes())["type"] == "xviz/state_update"]
    paths = sorted(updates, key=lambda path: int(path.name.split("-")[0]))[: args.frames]
    rows = asyncio.run(run(paths, args.repeat))
    print(f"{len(paths)} KITTI frames, CPU ms per frame in a worker process, least of {args.repeat} runs")
    print(
        f"{'level':8} {'median':>7} {'largest':>8} {'bare libraries':>15} {'x bare':>7} {'bare images':>12} {'bytes':>6}"
    )
    for row in rows:
        print(
            f"{row['level']:8} {row['median']:7.2f} {row['largest']:8.2f} {row['bare']:15.2f} "
            f"{row['median'] / row['bare']:7.2f} {row['bare_images']:12.2f} {row['share']:6.1%}"
        )


if __name__ == "__main__":
    main()
