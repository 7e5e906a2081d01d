"""The scripted XVIZ client for CI smoke tests: ``xviz-server probe URL`` (see :mod:`.client`)."""

from .client import POSE_WINDOW, probe, with_format
from .report import Instant, ProbeReport, Problem

__all__ = ["probe", "ProbeReport", "Problem", "Instant", "POSE_WINDOW", "with_format"]
