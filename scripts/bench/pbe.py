#!/usr/bin/env python3
"""Benchmark serving protobuf (PBE) frames: PBE -> GLB, the transcode each frame of a PBE log gets once.

    python scripts/bench/pbe.py [PBE_LOG_DIR] [--repeat N] [--quick]

Without a log, the KITTI excerpt (25 frames of about 121 000 points and four
camera images) is written as PBE by @xviz/io 1.0.13's XVIZProtobufWriter
(``tests/interop/xviz-write.js``; run ``npm ci --prefix tests/interop``
first). Prints, for its first frame, the median time of decoding it, of
turning it into a GLB frame and into a JSON one, with references measured in
the same run: copying the frame's bytes once, and re-encoding the same frame
read from GLB. Then the same transcode for every frame of the log in turn,
each read from its file and the result kept as the frame cache keeps it,
against the KITTI GLB files going through the same steps.

It also prints page faults per frame: the PBE path allocates about 6 MB per
frame (the runtime's copy of the points and images, Python's copy of them,
the GLB), and when malloc hands that memory back to the kernel after each
frame, faulting it in again can cost far more than the decoding. Run with
``MALLOC_TRIM_THRESHOLD_=268435456 MALLOC_MMAP_THRESHOLD_=33554432`` to see
the time with memory reused.
"""

from __future__ import annotations

import argparse
import resource
import shutil
import statistics
import subprocess
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from kit import KITTI as KITTI_LOG
from kit import REPO as REPOSITORY
from kit import median_ms, parse

from xviz_server.codec import Format, decode_pbe, encode
from xviz_server.frames import render


def faults() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt


def measure(function: Callable[[], Any], repeat: int) -> tuple[float, float]:
    """The median time of ``function`` in milliseconds, and its page faults per run."""
    before = faults()
    ms = median_ms(function, repeat)
    return ms, (faults() - before) / (repeat + 1)  # median_ms runs it once more to warm up


def serve_each_frame(files: list[Path], rounds: int) -> tuple[float, float, float]:
    """Median and 90th percentile ms, and median page faults, of transcoding each file to GLB.

    Each file is read before its clock starts; the GLBs are kept, as the
    frame cache keeps them, up to a log's worth.
    """
    kept: list[bytes] = []
    times, counts = [], []
    for _ in range(rounds):
        for file in files:
            data = file.read_bytes()
            before, start = faults(), time.perf_counter()
            kept.append(render(data, Format.BINARY, None))
            times.append((time.perf_counter() - start) * 1000)
            counts.append(faults() - before)
            del kept[: -len(files)]
    times.sort()
    return statistics.median(times), times[int(len(times) * 0.9)], statistics.median(counts)


def kitti_as_pbe(directory: Path) -> Path:
    """The KITTI excerpt written by @xviz/io's protobuf writer into ``directory``."""
    node = shutil.which("node")
    if node is None:
        raise SystemExit("node is needed to write the PBE log with @xviz/io")
    script = REPOSITORY / "tests" / "interop" / "xviz-write.js"
    subprocess.run([node, str(script), str(KITTI_LOG), f"BINARY_PBE:{directory}"], check=True)
    return directory


def frames_of(directory: Path, suffix: str) -> list[Path]:
    files = [p for p in directory.glob(f"*-frame{suffix}") if int(p.name.partition("-")[0]) >= 2]
    return sorted(files, key=lambda p: int(p.name.partition("-")[0]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("log", nargs="?", type=Path)
    parser.add_argument("--repeat", type=int, default=50)
    parser.add_argument("--rounds", type=int, default=3, help="passes over the whole log")
    args = parse(parser, quick={"repeat": 3, "rounds": 1})

    with tempfile.TemporaryDirectory() as scratch:
        log = args.log or kitti_as_pbe(Path(scratch) / "pbe")
        files = frames_of(log, ".pbe")
        data = files[0].read_bytes()
        message = decode_pbe(data)
        glb = encode(message, Format.BINARY)
        points = sum(
            len(point["points"])
            for update in message["data"]["updates"]
            for primitives in (update.get("primitives") or {}).values()
            for point in primitives.get("points") or ()
        )
        rows = [
            ("copy frame bytes (reference)", measure(lambda: bytearray(data), args.repeat)),
            ("PBE decode", measure(lambda: decode_pbe(data), args.repeat)),
            ("PBE -> GLB", measure(lambda: render(data, Format.BINARY, None), args.repeat)),
            ("GLB -> GLB (same frame, reference)", measure(lambda: render(glb, Format.BINARY, None), args.repeat)),
            ("PBE -> JSON", measure(lambda: render(data, Format.JSON, None), max(5, args.repeat // 10))),
        ]
        copy_ms = rows[0][1][0]
        print(f"frame: {files[0].name} ({len(data) / 1e6:.2f} MB, {points} points)")
        print(f"{'operation':40} {'median ms':>10} {'x copy':>8} {'faults':>8}")
        for name, (ms, count) in rows:
            print(f"{name:40} {ms:10.3f} {ms / copy_ms:8.2f} {count:8.0f}")

        print(f"\neach frame of the log once, {args.rounds} rounds, GLBs kept as the cache keeps them:")
        print(f"{'frames':40} {'median ms':>10} {'p90 ms':>8} {'faults':>8}")
        for name, frames in (
            (f"{log.name}: PBE -> GLB", files),
            ("KITTI GLB -> GLB (reference)", frames_of(KITTI_LOG, ".glb")),
        ):
            median, p90, count = serve_each_frame(frames, args.rounds)
            print(f"{name:40} {median:10.3f} {p90:8.2f} {count:8.0f}")


if __name__ == "__main__":
    main()
