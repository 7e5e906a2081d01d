#!/usr/bin/env python3
"""Conversion speed per frame of every dataset kind, side by side, in one process.

    python scripts/bench/datasets.py [--frames N] [--quick]

KITTI is the real drive in shared/data; Waymo, VISTA, nuScenes, Argoverse 2
and PandaSet frames are generated at their real sizes (Waymo: a 64 x 2650 top range image, four 200 x 600
short-range ones and five 1920 x 1280 camera images, both as the per-frame
.npz dictionaries and as a .tfrecord segment of Frame messages with both
returns, the TOP per-pixel pose and JPEG cameras; VISTA: one 1280 x 720
camera video and 100 000-point lidar sweeps; nuScenes, Argoverse 2 and
PandaSet: KITTI-size sweeps of 120 000 points in each layout, with their
cameras' photo-like JPEGs at the datasets' sizes). Each frame is converted and
encoded as GLB; the report gives the median milliseconds per frame, the first
frame's (opening the dataset included) and the encoded size.
"""

from __future__ import annotations

import argparse
import io
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from kit import KITTI_RAW as KITTI
from kit import parse

from devkit.waymo_frames import real_size_frame, write_segment
from xviz_server.codec import Format, encode
from xviz_server.datasets import open_dataset
from xviz_server.messages import envelope


def waymo_segment(directory: Path, frames: int) -> Path:
    rng = np.random.default_rng(0)
    directory.mkdir()
    for i in range(frames):
        arrays: dict[str, np.ndarray] = {"POSE": np.eye(4, dtype=np.float32)}
        for lidar, shape in (
            ("TOP", (64, 2650)),
            ("FRONT", (200, 600)),
            ("SIDE_LEFT", (200, 600)),
            ("SIDE_RIGHT", (200, 600)),
            ("REAR", (200, 600)),
        ):
            image = rng.uniform(0, 50, (*shape, 6)).astype(np.float32)
            image[rng.uniform(size=shape) < 0.3, 0] = 0  # no return
            arrays[f"{lidar}_RANGE_IMAGE_FIRST_RETURN"] = image
        for camera in ("FRONT", "FRONT_LEFT", "FRONT_RIGHT", "SIDE_LEFT", "SIDE_RIGHT"):
            arrays[f"{camera}_IMAGE"] = rng.integers(0, 255, (1280, 1920, 3), dtype=np.uint8)
        arrays["LABEL_BOXES"] = np.column_stack(
            [rng.uniform(-40, 40, (60, 3)), rng.uniform(1, 5, (60, 3)), rng.uniform(-3, 3, 60)]
        )
        arrays["LABEL_TYPES"] = rng.integers(0, 5, 60)
        arrays["LABEL_IDS"] = np.array([f"obj-{k}" for k in range(60)])
        np.savez(directory / f"{1_557_000_000_000_000 + i * 100_000}.npz", **arrays)  # type: ignore[arg-type]  # numpy's stub takes **arrays for allow_pickle
    return directory


def waymo_tfrecord(
    path: Path, frames: int, returns_top: tuple[float, float], returns_short: tuple[float, float]
) -> Path:
    from PIL import Image

    rng = np.random.default_rng(0)
    cameras = {}
    for camera in ("FRONT", "FRONT_LEFT", "FRONT_RIGHT", "SIDE_LEFT", "SIDE_RIGHT"):
        # A photo-like JPEG: smooth shading and grain.
        shade = np.linspace(0, 200, 1920)[None, :, None] + np.linspace(0, 50, 1280)[:, None, None]
        pixels = np.clip(shade + rng.normal(0, 8, (1280, 1920, 3)), 0, 255).astype(np.uint8)
        out = io.BytesIO()
        Image.fromarray(pixels).save(out, format="JPEG", quality=90)
        cameras[camera] = out.getvalue()
    return write_segment(
        path,
        [
            real_size_frame(1_557_000_000_000_000 + i * 100_000, rng, cameras, returns_top, returns_short)
            for i in range(frames)
        ],
    )


def vista_trace(directory: Path, frames: int) -> Path:
    import av
    import h5py

    rng = np.random.default_rng(0)
    directory.mkdir()
    with av.open(str(directory / "camera_front.avi"), "w", format="avi") as container:
        stream = container.add_stream("mjpeg", rate=30)
        stream.width, stream.height, stream.pix_fmt = 1280, 720, "yuvj420p"
        for _ in range(frames):
            image = rng.integers(0, 255, (720, 1280, 3), dtype=np.uint8)
            for packet in stream.encode(av.VideoFrame.from_ndarray(image, format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    start = 1_600_000_000.0
    (directory / "camera_front.csv").write_text(
        "frame_num,ros_timestamp\n" + "".join(f"{n},{start + n / 30:.4f}\n" for n in range(frames))
    )
    with h5py.File(directory / "lidar_3d.h5", "w") as file:
        file["xyz"] = rng.uniform(-50, 50, (frames, 100_000, 3)).astype(np.float32)
        file["intensity"] = rng.uniform(0, 1, (frames, 100_000)).astype(np.float32)
    (directory / "lidar_3d.csv").write_text(
        "frame_num,ros_timestamp\n" + "".join(f"{n},{start + n / 30:.4f}\n" for n in range(frames))
    )
    t = start + np.arange(-30, frames * 2) / 30
    (directory / "speed.csv").write_text("".join(f"{x:.4f},10\n" for x in t))
    (directory / "imu.csv").write_text("".join(f"{x:.4f},0,0,0,0,0,0.1,0\n" for x in t))
    return directory


KITTI_POINTS = 120_000


def photo(width: int, height: int, rng: np.random.Generator) -> bytes:
    """A photo-like JPEG: smooth shading and grain."""
    from PIL import Image

    shade = np.linspace(0, 200, width)[None, :, None] + np.linspace(0, 50, height)[:, None, None]
    pixels = np.clip(shade + rng.normal(0, 8, (height, width, 3)), 0, 255).astype(np.uint8)
    out = io.BytesIO()
    Image.fromarray(pixels).save(out, format="JPEG", quality=90)
    return out.getvalue()


def real_size(folder: Path, sweeps: str, write: Any, image: tuple[int, int]) -> None:
    """The sweeps (files matching ``sweeps``) rewritten with KITTI-size clouds by ``write``, and every JPEG at ``image``."""
    rng = np.random.default_rng(0)
    cloud = rng.uniform(-60, 60, (KITTI_POINTS, 3))
    for path in folder.rglob(sweeps):
        write(path, cloud, rng.uniform(0, 255, KITTI_POINTS))
    jpeg = photo(*image, rng)
    for path in folder.rglob("*.jpg"):
        path.write_bytes(jpeg)


def nuscenes_root(directory: Path, frames: int) -> Path:
    from devkit.nuscenes_scene import write_nuscenes

    written = write_nuscenes(directory, keys=max(2, frames // 10 + 1))

    def write(path: Path, cloud: np.ndarray, intensity: np.ndarray) -> None:
        path.write_bytes(np.column_stack([cloud, intensity, np.zeros(len(cloud))]).astype("<f4").tobytes())

    real_size(directory, "*.pcd.bin", write, (1600, 900))
    return written.root


def argoverse2_log(directory: Path, frames: int) -> Path:
    import pyarrow as pa
    import pyarrow.feather as feather

    from devkit.argoverse2_log import write_av2_log

    def write(path: Path, cloud: np.ndarray, intensity: np.ndarray) -> None:
        feather.write_feather(
            pa.table(
                {
                    "x": cloud[:, 0].astype(np.float16),
                    "y": cloud[:, 1].astype(np.float16),
                    "z": cloud[:, 2].astype(np.float16),
                    "intensity": intensity.astype(np.uint8),
                }
            ),
            path,
        )

    folder = write_av2_log(directory / "log", sweeps=frames).folder
    real_size(folder, "*.feather", lambda p, c, i: write(p, c, i) if p.parent.name == "lidar" else None, (2048, 1550))
    return folder


def pandaset_sequence(directory: Path, frames: int) -> Path:
    import pandas as pd

    from devkit.pandaset_sequence import write_sequence

    def write(path: Path, cloud: np.ndarray, intensity: np.ndarray) -> None:
        if path.parent.name == "lidar":
            pd.DataFrame(
                {"x": cloud[:, 0], "y": cloud[:, 1], "z": cloud[:, 2], "i": intensity, "t": 0.0, "d": 0}
            ).to_pickle(path, compression="gzip")

    folder = write_sequence(directory / "001", sweeps=frames)
    real_size(folder, "*.pkl.gz", write, (1920, 1080))
    return folder


def per_frame(kind: str, path: Path, frames: int, options: dict[str, Any]) -> tuple[float, float, int]:
    """The median and the first frame's milliseconds (opening the dataset included), and the GLB size."""
    started = time.perf_counter()
    dataset = open_dataset(kind, path, **options)
    metadata = dataset.metadata()
    times, size = [], 0
    for frame in range(min(frames, len(dataset))):
        data = encode(envelope("state_update", dataset.convert(frame, metadata)), Format.BINARY)
        times.append(time.perf_counter() - started)
        started = time.perf_counter()
        size = len(data)
    return statistics.median(times[1:] or times) * 1000, times[0] * 1000, size


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=10)
    args = parse(parser, quick={"frames": 1})
    with tempfile.TemporaryDirectory() as scratch:
        scaled: dict[str, Any] = {}  # cameras scaled down to the default 400 pixels
        rows = [("kitti", KITTI, scaled, "real drive 0001 excerpt")]
        npz = waymo_segment(Path(scratch) / "waymo", args.frames)
        rows.append(("waymo", npz, scaled, ".npz generated at real size (returns 70% of every lidar)"))
        # As many first returns as the .npz row, plus second returns; then the TOP lidar nearly full and the
        # short-range ones (20 m reach) sparse, as in a street scene; that one also with the JPEGs passed through.
        for label, top, short in (
            ("as dense as .npz", (0.7, 0.1), (0.7, 0.1)),
            ("street-like", (0.9, 0.1), (0.1, 0.01)),
        ):
            tfrecord = waymo_tfrecord(Path(scratch) / f"waymo-{len(rows)}.tfrecord", args.frames, top, short)
            returns = f"returns TOP {top[0]:.0%}+{top[1]:.0%}, short-range {short[0]:.0%}+{short[1]:.0%}"
            rows.append(
                (
                    "waymo",
                    tfrecord,
                    scaled,
                    f".tfrecord {label}: {returns}, {tfrecord.stat().st_size / args.frames / 1e6:.1f} MB/frame",
                )
            )
        rows.append(
            (
                "waymo",
                tfrecord,
                {"image_max_width": 1920},
                ".tfrecord street-like, JPEGs passed through (--image-max-width 1920)",
            )
        )
        rows.append(("vista", vista_trace(Path(scratch) / "vista", args.frames), scaled, "generated at real size"))
        rows.append(
            (
                "nuscenes",
                nuscenes_root(Path(scratch) / "nuscenes", args.frames),
                scaled,
                "120 000-point sweeps, 1600 x 900 cameras",
            )
        )
        rows.append(
            (
                "argoverse2",
                argoverse2_log(Path(scratch) / "av2", args.frames),
                scaled,
                "120 000-point float16 sweeps, 2048 x 1550 cameras",
            )
        )
        rows.append(
            (
                "pandaset",
                pandaset_sequence(Path(scratch) / "pandaset", args.frames),
                scaled,
                "120 000-point pickled sweeps, 1920 x 1080 cameras",
            )
        )
        print(f"{'dataset':10} {'ms/frame':>9} {'first ms':>9} {'GLB size':>10}  input")
        reference = first_reference = None
        for kind, path, options, note in rows:
            ms, first, size = per_frame(kind, path, args.frames, options)
            reference, first_reference = reference or ms, first_reference or first
            print(
                f"{kind:10} {ms:9.1f} {first:9.1f} {size / 1e6:8.2f} MB  {note} "
                f"({ms / reference:.1f}x KITTI, first {first / first_reference:.1f}x)"
            )


if __name__ == "__main__":
    main()
