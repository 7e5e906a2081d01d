#!/usr/bin/env python3
"""Measure the built-in viewer: page load to first drawn frame, where the time goes, and the bundle's size.

    .venv/bin/python scripts/bench/viewer.py [--runs N] [--kitti DIR] [--viewport WxH ...] [--quick]

Starts the server (``python -m xviz_server serve --data-dir`` a folder holding the
KITTI excerpt, ``--port 0``) and, for each viewport, opens
``/?log=<kitti>`` ``--runs`` times in headless Chromium (``tests/browser.mjs``, a fresh
browser and profile each time) and reports the medians, in ms after the browser
opened the tab, of the way to the first drawn frame, as the page's own timings
(resource timing and the User Timing marks of ``viewer/src/timing.js``) tell it:
the script bundle received, the bundle run (``script``), the catalog fetched, the
WebSocket open, the metadata, the first frame the 3D view can draw, the GPU done
drawing it (``first-draw``), and that frame shown (when a screenshot of the 3D view
that is not blank was taken: the time after the first frame is the GPU's, compiling
shaders and drawing, and the compositor's). Screenshots are taken once the page has
the metadata and the first frame (two messages): the page asks for the rest of its
buffer only after it drew that frame. The reference, measured in the
same run, is the same browser loading the page without waiting for anything (the
catalog page, ``/``): the ratio says what the 3D view costs on top of opening a
tab. WebGL runs on SwiftShader (the CPU), so the numbers depend on the machine and
its load: the script says how busy the machine was.

The bundle's size is that of its files (raw, gzip, brotli) and of those the page
loaded for the KITTI log (the base map's chunk is loaded only with a map token).

Needs ``scripts/build-viewer.sh`` (the bundle, playwright-core) and chromium.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

from kit import KITTI, REPO, parse
from kit.proc import start_server

DRIVER = REPO / "tests" / "browser.mjs"
STATIC = REPO / "xviz_server" / "viewer_static"


def drive(options: dict[str, Any]) -> dict[str, Any]:
    """One run of the browser driver; its report."""
    result = subprocess.run(["node", str(DRIVER), json.dumps(options)], capture_output=True, text=True, check=True)
    report: dict[str, Any] = json.loads(result.stdout)
    return report


#: The stages of the way to the first drawn frame, as browser.mjs reports them.
STAGES = ("bundle", "script", "catalog", "socket-open", "metadata", "first-frame", "first-draw")


def bundle_sizes(names: list[str] | None = None) -> dict[str, int]:
    """Bytes of the bundle's assets (JS and CSS; those named, or all), raw, gzip and brotli."""
    assets = [path for path in STATIC.iterdir() if re.fullmatch(r"(viewer|asset)-[A-Z0-9]+\.\w+", path.name)]
    assets = [path for path in assets if names is None or path.name in names]
    return {
        "raw": sum(path.stat().st_size for path in assets),
        "gzip": sum(path.with_name(path.name + ".gz").stat().st_size for path in assets),
        "brotli": sum(path.with_name(path.name + ".br").stat().st_size for path in assets),
    }


def megabytes(sizes: dict[str, int]) -> str:
    return f"{sizes['raw'] / 1e6:.2f} MB raw, {sizes['gzip'] / 1e6:.2f} MB gzip, {sizes['brotli'] / 1e6:.2f} MB brotli"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--kitti", type=Path, default=KITTI)
    parser.add_argument("--viewport", nargs="+", default=["1280x800", "800x500"])
    args = parse(parser, quick={"runs": 1, "viewport": ["800x500"]})

    print(f"bundle (JS + CSS), all files: {megabytes(bundle_sizes())}")
    with tempfile.TemporaryDirectory() as data_dir:
        (Path(data_dir) / args.kitti.name).symlink_to(args.kitti.resolve())
        with start_server(data_dir) as server:
            base = f"http://127.0.0.1:{server.port}"
            load_before = os.getloadavg()[0]
            started = time.monotonic()
            reference = [drive({"url": f"{base}/", "draw": False, "settle": 0})["loadedMs"] for _ in range(args.runs)]
            print(f"reference, the catalog page loaded: median {statistics.median(reference):.0f} ms of {args.runs}")
            for viewport in args.viewport:
                width, height = (int(n) for n in viewport.split("x"))
                options = {
                    "url": f"{base}/?log={args.kitti.name}",
                    "viewport": {"width": width, "height": height},
                    "settle": 0,
                    "timeout": 120_000,
                    "frames": 2,
                }
                reports = [drive(options) for _ in range(args.runs)]
                if not all(report["drawn"] for report in reports):
                    print(f"{viewport}: the 3D view was not drawn in every run: {reports}")
                    continue
                drawn = statistics.median(report["firstDrawnMs"] for report in reports)
                # A page built before a stage had its mark reports the stages it has.
                known = [stage for stage in STAGES if all(stage in r["marks"] for r in reports)]
                stages = ", ".join(
                    f"{stage} {statistics.median(r['marks'][stage] for r in reports):.0f}" for stage in known
                )
                print(
                    f"{viewport}: {stages}, shown {drawn:.0f} ms (median of {args.runs}; "
                    f"{drawn / statistics.median(reference):.1f} x the reference)"
                )
                loaded = [asset["name"] for asset in reports[0]["assets"]]
                print(f"  the page loaded {len(loaded)} of the bundle's files: {megabytes(bundle_sizes(loaded))}")
            elapsed = time.monotonic() - started
            print(
                f"machine load average {load_before:.1f} before, {os.getloadavg()[0]:.1f} after; {elapsed:.0f} s in all; {os.cpu_count()} cores"
            )


if __name__ == "__main__":
    main()
