#!/usr/bin/env python3
"""Benchmark the XVIZ codecs on a real KITTI frame.

    python scripts/bench/codec.py [FRAME.glb] [--repeat N] [--quick]

Prints the median time of GLB decode (to numpy views), GLB encode (from
numpy), JSON encode and decode, with two references measured in the same
run: copying the frame's bytes once (the floor for any encoder), and the
libraries we chose not to use on the hot path (pygltflib for GLB, the
standard library's json for JSON).
"""

from __future__ import annotations

import argparse
import json
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pygltflib
from kit import KITTI_FRAME, median_ms, parse

from xviz_server.codec import decode_glb, decode_json, encode_glb, encode_json


def stdlib_json(message: Any) -> str:
    def default(value: Any) -> Any:
        if isinstance(value, np.ndarray):
            return value.tolist()
        if isinstance(value, memoryview):
            import base64

            return base64.b64encode(value).decode()
        raise TypeError(type(value))

    return json.dumps(message, default=default, separators=(",", ":"))


def pygltflib_load(data: bytes) -> Any:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return pygltflib.GLTF2.load_from_bytes(data)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("frame", nargs="?", type=Path, default=KITTI_FRAME)
    parser.add_argument("--repeat", type=int, default=50)
    args = parse(parser, quick={"repeat": 3})

    data = args.frame.read_bytes()
    message = decode_glb(data)
    cloud = message["data"]["updates"][0]["primitives"]["/lidar/points"]["points"][0]
    glb = encode_glb(message)
    text = encode_json(message)

    rows = [
        ("copy frame bytes (reference)", median_ms(lambda: bytes(bytearray(data)), args.repeat), len(data)),
        ("GLB decode -> numpy views", median_ms(lambda: decode_glb(data), args.repeat), len(data)),
        ("GLB encode <- numpy", median_ms(lambda: encode_glb(message), args.repeat), len(glb)),
        ("pygltflib load (reference)", median_ms(lambda: pygltflib_load(data), args.repeat), len(data)),
        ("JSON encode (orjson)", median_ms(lambda: encode_json(message), max(5, args.repeat // 5)), len(text)),
        ("JSON encode (stdlib json, reference)", median_ms(lambda: stdlib_json(message), 5), None),
        ("JSON decode (orjson)", median_ms(lambda: decode_json(text), max(5, args.repeat // 5)), len(text)),
        ("JSON decode (stdlib json, reference)", median_ms(lambda: json.loads(text), 5), None),
    ]
    copy_ms = rows[0][1]
    print(f"frame: {args.frame} ({len(data) / 1e6:.2f} MB, {len(cloud['points'])} points)")
    print(f"{'operation':40} {'median ms':>10} {'x copy':>8} {'bytes':>11}")
    for name, ms, size in rows:
        print(f"{name:40} {ms:10.3f} {ms / copy_ms:8.2f} {size if size is not None else '':>11}")
    print(
        f"GLB decode is {rows[3][1] / rows[1][1]:.0f}x faster than pygltflib's load; "
        f"orjson encodes {rows[5][1] / rows[4][1]:.1f}x faster than the standard library"
    )


if __name__ == "__main__":
    main()
