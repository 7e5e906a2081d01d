"""Where the project's real data is: the shared folder, read once from ``XVIZ_SHARED_DIR``.

The folder holds the conformance corpus and the real KITTI excerpt (the
official 25-frame GLB log and the same drive in KITTI raw layout). By
default it is ``shared/`` beside the repository (``../shared`` from its root).
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = [
    "SHARED_DIR",
    "DATA",
    "KITTI_LOG",
    "KITTI_RAW",
    "KITTI_FRAME",
    "FIXTURES",
    "SCHEMA_EXAMPLES",
    "MISSING",
    "present",
]

#: The shared folder: ``$XVIZ_SHARED_DIR``, else ``shared/`` beside the repository.
SHARED_DIR = Path(os.environ.get("XVIZ_SHARED_DIR") or Path(__file__).resolve().parents[2] / "shared")
DATA = SHARED_DIR / "data"
#: The official 25-frame KITTI log (GLB), drive 0001 of 2011_09_26.
KITTI_LOG = DATA / "kitti-2011_09_26_drive_0001-head"
#: The same drive in KITTI raw layout (date folder with the calibration, drive folder).
KITTI_RAW = DATA / "kitti-raw-2011_09_26_drive_0001-head"
#: One 2.14 MB KITTI frame (121 015 points, four PNGs).
KITTI_FRAME = KITTI_LOG / "2-frame.glb"
FIXTURES = SHARED_DIR / "conformance" / "fixtures"
SCHEMA_EXAMPLES = SHARED_DIR / "conformance" / "schema-examples"

#: The one line a test that needs the real data skips with, when it is missing.
MISSING = f"no real data at {SHARED_DIR}: get it with scripts/get-data.sh (docs/testing.md)"


def present() -> bool:
    """Whether the KITTI excerpt (both layouts) and the conformance corpus are there."""
    return all(path.is_dir() for path in (KITTI_LOG, KITTI_RAW, FIXTURES, SCHEMA_EXAMPLES))
