"""Shared fixtures: where the real data lives, and a clean logging set-up for each test."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from devkit.data import KITTI_LOG, SHARED_DIR
from helpers import require_data


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """The project's shared folder: conformance corpus and real KITTI data.

    Without it a test skips with one line saying how to get it (in CI, which
    has the data, it fails instead).
    """
    require_data()
    return SHARED_DIR


@pytest.fixture(scope="session")
def kitti_log(shared_dir: Path) -> Path:
    """The official 25-frame KITTI GLB log."""
    return KITTI_LOG


@pytest.fixture
def kitti_root(tmp_path: Path, kitti_log: Path) -> Path:
    """A data directory holding the official KITTI log as ``kitti``."""
    data = tmp_path / "logs"
    data.mkdir()
    (data / "kitti").symlink_to(kitti_log)
    return data


@pytest.fixture(autouse=True)
def _restore_logging():
    """Undo what an in-process ``xviz-server`` command does to the root logger.

    The command points the root logger at the standard error it was given;
    under pytest that stream is closed when the test ends, and every later
    log line would fail on it.
    """
    root = logging.getLogger()
    handlers, level = root.handlers[:], root.level
    yield
    root.handlers[:] = handlers
    root.setLevel(level)
