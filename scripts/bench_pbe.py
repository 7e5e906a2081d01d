#!/usr/bin/env python3
"""Benchmark serving a protobuf (PBE) frame: PBE -> GLB, the transcode a PBE log's frame gets once.

    python scripts/bench_pbe.py [FRAME.pbe] [--repeat N]

Without a frame, the KITTI frame ``2-frame.glb`` (121 015 points, four
camera images) is written as PBE by @xviz/io 1.0.13's XVIZProtobufWriter
(``tests/interop/xviz-write.js``; run ``npm ci --prefix tests/interop``
first). Prints the median time of decoding the PBE frame, of turning it into
a GLB frame and into a JSON one, with references measured in the same run:
copying the frame's bytes once, and re-encoding the same frame read from GLB.

It also prints the page faults per run: the PBE path allocates about 6 MB
per frame (the runtime's copy of the points and images, Python's copy of
them, the GLB), and when malloc hands that memory back to the kernel after
each frame, faulting it in again can cost far more than the decoding. Run
with ``MALLOC_TRIM_THRESHOLD_=268435456 MALLOC_MMAP_THRESHOLD_=33554432`` to
see the time with memory reused.
"""

from __future__ import annotations

import argparse
import resource
import shutil
import subprocess
import tempfile
from pathlib import Path
from typing import Any, Callable

from bench_codec import median_ms

from xviz_server.codec import Format, decode_pbe, encode
from xviz_server.frames import render

REPOSITORY = Path(__file__).resolve().parents[1]
KITTI_LOG = REPOSITORY.parent / "shared" / "data" / "kitti-2011_09_26_drive_0001-head"


def measure(function: Callable[[], Any], repeat: int) -> tuple[float, float]:
    """The median time of ``function`` in milliseconds, and its page faults per run."""
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    ms = median_ms(function, repeat)
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults
    return ms, faults / (repeat + 1)  # median_ms runs it once more to warm up


def kitti_frame_as_pbe(directory: Path) -> Path:
    """KITTI's first state update written by @xviz/io's protobuf writer into ``directory``."""
    source = directory / "source"
    source.mkdir()
    for name in ("1-frame.glb", "2-frame.glb"):
        (source / name).symlink_to(KITTI_LOG / name)
    node = shutil.which("node")
    if node is None:
        raise SystemExit("node is needed to write the PBE frame with @xviz/io")
    script = REPOSITORY / "tests" / "interop" / "xviz-write.js"
    subprocess.run([node, str(script), str(source), f"BINARY_PBE:{directory / 'pbe'}"], check=True)
    return directory / "pbe" / "2-frame.pbe"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("frame", nargs="?", type=Path)
    parser.add_argument("--repeat", type=int, default=50)
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as scratch:
        path = args.frame or kitti_frame_as_pbe(Path(scratch))
        data = path.read_bytes()
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
        ("PBE -> GLB (served once per frame)", measure(lambda: render(data, Format.BINARY, None), args.repeat)),
        ("GLB -> GLB (same frame, reference)", measure(lambda: render(glb, Format.BINARY, None), args.repeat)),
        ("PBE -> JSON", measure(lambda: render(data, Format.JSON, None), max(5, args.repeat // 10))),
    ]
    copy_ms = rows[0][1][0]
    print(f"frame: {path.name} ({len(data) / 1e6:.2f} MB, {points} points)")
    print(f"{'operation':40} {'median ms':>10} {'x copy':>8} {'faults':>8}")
    for name, (ms, faults) in rows:
        print(f"{name:40} {ms:10.3f} {ms / copy_ms:8.2f} {faults:8.0f}")


if __name__ == "__main__":
    main()
