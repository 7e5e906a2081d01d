"""Every benchmark in ``scripts/bench/`` still runs: each one's ``--quick`` mode, as CI runs it.

A quick run takes a few seconds and measures nothing worth reading; what it
shows is that the benchmark's code paths (servers, clients, references,
generated data) still work against the current product, and that it printed
its results: at least one row of figures. Nothing here asserts a time.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from helpers import needs_data

BENCH = Path(__file__).resolve().parents[1] / "scripts" / "bench"
BENCHMARKS = sorted(path.stem for path in BENCH.glob("*.py"))
#: A row of results: a line with at least three figures (values, ratios, sizes).
ROW = re.compile(r"^(?=(?:.*?\d+(?:\.\d+)?){3}).*$", re.M)
#: What some benchmarks need beyond the package: a program on the PATH, or the viewer bundle.
NEEDS = {
    "broker": "redis-server",
    "wire": "redis-server",
    "pbe": "node",
    "viewer": "chromium",
}

pytestmark = [
    pytest.mark.slow,
    needs_data,
]


def test_every_benchmark_is_here() -> None:
    """The list is read from the folder: a benchmark added there is run below."""
    assert {"server", "send", "live", "store"} <= set(BENCHMARKS)


@pytest.mark.parametrize("name", BENCHMARKS)
def test_quick_run(name: str) -> None:
    needed = NEEDS.get(name)
    if needed and shutil.which(needed) is None:
        pytest.skip(f"needs {needed}: run scripts/test.sh")
    if name == "links" and os.geteuid() != 0:
        pytest.skip("shapes a veth pair with tc: needs root")
    if name == "viewer" and not (BENCH.parents[1] / "xviz_server" / "viewer_static" / "index.html").is_file():
        pytest.skip("needs the viewer bundle: run scripts/build-viewer.sh")
    env = {k: v for k, v in os.environ.items() if not k.startswith("XVIZ_") or k == "XVIZ_SHARED_DIR"}
    result = subprocess.run(
        [sys.executable, str(BENCH / f"{name}.py"), "--quick"],
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
        cwd=BENCH.parents[1],
    )
    assert result.returncode == 0, f"exit {result.returncode}\n{result.stdout[-3000:]}\n{result.stderr[-3000:]}"
    assert ROW.search(result.stdout), f"no row of results in:\n{result.stdout[-3000:]}"
