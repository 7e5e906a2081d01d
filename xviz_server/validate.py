"""Check XVIZ files and log directories against the schema: ``xviz-server validate``.

A file is decoded (GLB, JSON or PBE), its envelope recognised and its content
validated against the XVIZ v2 schema. A log directory in the reference
layout is checked as a whole as well: ``1-frame`` must be the metadata,
every later frame a state update, the index (``0-frame.json``) must name
exactly the frames present with their real time spans, and streams that
frames carry without the metadata declaring them are reported as warnings.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import orjson

from .codec import decode
from .exceptions import DecodeError, MessageError, SchemaValidationError
from .layout import (
    INDEX_FILE,
    INDEX_NUMBER,
    LOG,
    METADATA_NUMBER,
    discover,
    file_number,
    frame_files,
    frame_name,
    frame_numbers,
    update_span,
)
from .messages import unwrap
from .state import update_streams
from .timeindex import TimeIndex
from .validation import get_validator

__all__ = ["FileReport", "Report", "check_paths"]


@dataclass
class FileReport:
    """What was found in one file."""

    path: Path
    kind: str | None = None
    problems: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems


@dataclass
class Report:
    """Every file checked, in order."""

    files: list[FileReport]

    @property
    def ok(self) -> bool:
        return bool(self.files) and all(f.ok for f in self.files)

    def render(self) -> str:
        """A text report: one line per file, its problems and warnings indented below."""
        lines = []
        for report in self.files:
            status = "ok" if report.ok else "INVALID"
            lines.append(f"{report.path}  {status}  {report.kind or ''}".rstrip())
            lines += [f"    error: {p}" for p in report.problems]
            lines += [f"    warning: {w}" for w in report.warnings]
        invalid = sum(not f.ok for f in self.files)
        warnings = sum(len(f.warnings) for f in self.files)
        lines.append(
            f"{len(self.files)} files checked: {len(self.files) - invalid} ok, {invalid} invalid, {warnings} warnings"
        )
        return "\n".join(lines)

    def as_dict(self) -> dict[str, Any]:
        return {
            "ok": self.ok,
            "files": [
                {"path": str(f.path), "type": f.kind, "ok": f.ok, "problems": f.problems, "warnings": f.warnings}
                for f in self.files
            ],
        }


def check_paths(paths: Iterable[Path]) -> Report:
    """Check files, log directories, and directories holding logs at any depth."""
    reports: list[FileReport] = []
    for path in paths:
        if path.is_dir():
            logs = list(_log_directories(path))
            if not logs:
                reports.append(
                    FileReport(path, problems=["no XVIZ log (no N-frame.json/.glb/.pbe files) in this directory"])
                )
            for directory in logs:
                reports += check_log(directory)
        elif path.is_file():
            reports.append(_check_index(path) if path.name == INDEX_FILE else check_file(path)[0])
        else:
            reports.append(FileReport(path, problems=["no such file or directory"]))
    return Report(reports)


def _log_directories(root: Path) -> Iterator[Path]:
    return (found.path for found in discover(root) if found.kind == LOG)


def check_file(path: Path, expected: str | None = None) -> tuple[FileReport, Any]:
    """Check one message file; also return its decoded data (``None`` if unreadable)."""
    report = FileReport(path)
    try:
        kind, data = unwrap(decode(path.read_bytes()))
    except OSError as exc:
        report.problems.append(f"cannot read: {exc.strerror or exc}")
        return report, None
    except (DecodeError, MessageError) as exc:
        report.problems.append(str(exc))
        return report, None
    report.kind = kind
    if expected is not None and kind != expected:
        report.problems.append(f"holds {kind!r} where the log layout needs {expected!r}")
    try:
        get_validator().validate_message({"type": kind, "data": data})
    except SchemaValidationError as exc:
        report.problems += exc.problems
    return report, data


def _check_index(path: Path) -> FileReport:
    report = FileReport(path, kind="index")
    try:
        TimeIndex.from_reference(orjson.loads(path.read_bytes()), path.name)
    except (OSError, orjson.JSONDecodeError, DecodeError) as exc:
        report.problems.append(str(exc))
    return report


def check_log(directory: Path) -> list[FileReport]:
    """Check a log directory in the reference layout, file by file and as a whole."""
    files = {number: directory / name for number, name in frame_files(directory).items()}
    reports = []
    metadata_file = files.get(METADATA_NUMBER)
    declared: set[str] = set()
    if metadata_file is None:
        reports.append(FileReport(directory, problems=["no metadata file (1-frame.json, 1-frame.glb or 1-frame.pbe)"]))
    else:
        report, data = check_file(metadata_file, "xviz/metadata")
        reports.append(report)
        if isinstance(data, dict):
            declared = set(data.get("streams") or ())
    spans: dict[int, tuple[float, float]] = {}
    for frame in frame_numbers(files):
        report, data = check_file(files[file_number(frame)], "xviz/state_update")
        reports.append(report)
        span = update_span(data) if report.ok else None
        if span is not None:
            spans[frame] = span
            undeclared = sorted(update_streams(data) - declared)
            if undeclared and metadata_file is not None:
                report.warnings.append(f"streams not declared in the metadata: {', '.join(undeclared)}")
    reports.append(_check_log_index(directory, files, spans))
    return reports


def _check_log_index(directory: Path, files: dict[int, Path], spans: dict[int, tuple[float, float]]) -> FileReport:
    path = files.get(INDEX_NUMBER, directory / INDEX_FILE)
    if INDEX_NUMBER not in files:
        return FileReport(path, kind="index", warnings=["no index: servers must read every frame to build one"])
    report = _check_index(path)
    if not report.ok:
        return report
    index = TimeIndex.from_reference(orjson.loads(path.read_bytes()), path.name)
    present = set(frame_numbers(files))
    named = set(index.frames.tolist())
    if missing := sorted(named - present):
        report.problems.append(f"names frames with no file: {', '.join(frame_name(n) for n in missing[:10])}")
    unnamed = sorted(present - named)
    beyond = [
        n for n in unnamed if n > max(named, default=-1)
    ]  # written after the index, as a recording cut short leaves them
    if beyond:
        shown = ", ".join(frame_name(n) for n in beyond[:10]) + (
            f" and {len(beyond) - 10} more" if len(beyond) > 10 else ""
        )
        report.warnings.append(
            f"{len(beyond)} frames past the index (a recording cut short?): {shown}; servers read them"
        )
    if inside := [n for n in unnamed if n not in beyond]:
        report.problems.append(f"does not name frames that exist: {', '.join(frame_name(n) for n in inside[:10])}")
    for start, end, frame in zip(index.start.tolist(), index.end.tolist(), index.frames.tolist()):
        real = spans.get(frame)
        if real is not None and (abs(real[0] - start) > 1e-6 or abs(real[1] - end) > 1e-6):
            report.problems.append(
                f"frame {frame} ({frame_name(frame)}) spans {real[0]}-{real[1]}, the index says {start}-{end}"
            )
    return report
