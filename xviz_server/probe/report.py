"""What a probe found: :class:`ProbeReport`, and the :class:`Instant` type of its times."""

from __future__ import annotations

import math
import textwrap
from collections import Counter
from dataclasses import asdict, dataclass, field
from decimal import Decimal
from typing import Any

__all__ = ["Instant", "Problem", "ProbeReport"]

#: Errors, and warnings, that :meth:`ProbeReport.render` lists; ``as_dict`` has them all.
SHOWN_PROBLEMS = 20


@dataclass(frozen=True)
class Instant:
    """A time as given by the user: seconds, or seconds after the log's start."""

    seconds: float
    relative: bool = False

    @classmethod
    def parse(cls, text: str) -> Instant:
        """Read ``"1317042146.5"`` (absolute) or ``"+1.5"`` (after the log's start).

        Raises :class:`ValueError` for anything else.
        """
        try:
            seconds = float(text)
        except ValueError:
            raise ValueError(f"{text!r} is not a time: give seconds, or +seconds after the log's start") from None
        if not math.isfinite(seconds):
            raise ValueError(f"{text!r} is not a time: it must be a finite number of seconds")
        return cls(seconds, relative=text.lstrip().startswith("+"))

    def resolve(self, log_start: float | None) -> float:
        """This instant in absolute seconds, for a log that starts at ``log_start``.

        Raises :class:`ValueError` for an offset when the start is unknown.
        """
        if not self.relative:
            return self.seconds
        if log_start is None:
            raise ValueError(f"{self} needs the log's start_time, which the metadata lacks; give absolute times")
        # In decimal, so that +0.3 after 100.1 is the frame at 100.4, not 100.39999999999999.
        return float(Decimal(repr(log_start)) + Decimal(repr(self.seconds)))

    def __str__(self) -> str:
        return f"+{self.seconds:.15g}" if self.relative else f"{self.seconds}"


@dataclass(frozen=True)
class Problem:
    """Something wrong in a session: where it was seen, and what it was."""

    where: str
    what: str

    def __str__(self) -> str:
        return f"{self.where}: {self.what}"


@dataclass
class ProbeReport:
    """What a probe saw on one session.

    ``frames`` counts the state updates answering the ``transform_log``;
    ``messages`` and ``bytes_by_type`` count every message received, by type
    (the point-in-time answer is a ``xviz/state_update`` there, not a frame).
    ``first_time`` and ``last_time`` span the frames' timestamps.
    """

    url: str
    log_info: dict[str, Any] | None = None
    declared_streams: int = 0
    messages: Counter[str] = field(default_factory=Counter)
    bytes_by_type: Counter[str] = field(default_factory=Counter)
    frames: int = 0
    first_time: float | None = None
    last_time: float | None = None
    streams: set[str] = field(default_factory=set)
    elapsed: float = 0.0
    errors: list[Problem] = field(default_factory=list)
    warnings: list[Problem] = field(default_factory=list)

    @property
    def clean(self) -> bool:
        """Whether the session went without error (warnings allowed)."""
        return not self.errors

    @property
    def total_bytes(self) -> int:
        """Bytes received in all messages."""
        return sum(self.bytes_by_type.values())

    @property
    def megabytes_per_second(self) -> float:
        """Throughput over the whole session, connection included."""
        return self.total_bytes / 1e6 / self.elapsed if self.elapsed else 0.0

    def as_dict(self) -> dict[str, Any]:
        """The report as JSON-ready data."""
        return {
            "url": self.url,
            "clean": self.clean,
            "log_info": self.log_info,
            "declared_streams": self.declared_streams,
            "messages": dict(self.messages),
            "frames": self.frames,
            "bytes": {"total": self.total_bytes, "by_type": dict(self.bytes_by_type)},
            "time_range": {"first": self.first_time, "last": self.last_time},
            "streams": sorted(self.streams),
            "elapsed_s": round(self.elapsed, 3),
            "mb_per_s": round(self.megabytes_per_second, 1),
            "errors": [asdict(problem) for problem in self.errors],
            "warnings": [asdict(problem) for problem in self.warnings],
        }

    def render(self) -> str:
        """The report as a short text for people, one topic per line."""
        lines = [
            _line("probe", f"{self.url}: {'clean' if self.clean else 'UNCLEAN'}"),
            _line("log", self._log_summary()),
            _line("frames", self._frames_summary()),
            _line("streams", f"{len(self.streams)} seen: {', '.join(sorted(self.streams)) or '-'}"),
            _line(
                "received",
                f"{sum(self.messages.values())} messages, {self.total_bytes:,} bytes in {self.elapsed:.3f} s "
                f"({self.megabytes_per_second:.1f} MB/s)",
            ),
        ]
        width = max(map(len, self.messages), default=0)
        for kind, count in sorted(self.messages.items()):
            lines.append(_line("", f"{kind:<{width}} {count:>6} {self.bytes_by_type[kind]:>14,}"))
        lines += _problem_lines("errors", self.errors) + _problem_lines("warnings", self.warnings)
        return "\n".join(lines)

    def _log_summary(self) -> str:
        if self.log_info is None:
            return "no metadata"
        start, end = self.log_info.get("start_time"), self.log_info.get("end_time")
        return f"{start} to {end}, {self.declared_streams} streams declared"

    def _frames_summary(self) -> str:
        if self.first_time is None or self.last_time is None:
            return f"{self.frames}"
        span = self.last_time - self.first_time
        return f"{self.frames} from {self.first_time} to {self.last_time} ({span:.3f} s)"


_LABEL_WIDTH = 10


def _line(label: str, text: str) -> str:
    """``text`` under ``label``, wrapped, continuation lines indented like it."""
    return textwrap.fill(
        text,
        width=110,
        initial_indent=f"{label:<{_LABEL_WIDTH}}",
        subsequent_indent=" " * (_LABEL_WIDTH + 2),
        break_on_hyphens=False,
        break_long_words=False,
    )


def _problem_lines(label: str, problems: list[Problem]) -> list[str]:
    if not problems:
        return [_line(label, "none")]
    lines = [_line(label if i == 0 else "", str(problem)) for i, problem in enumerate(problems[:SHOWN_PROBLEMS])]
    if len(problems) > SHOWN_PROBLEMS:
        lines.append(_line("", f"... and {len(problems) - SHOWN_PROBLEMS} more (--json lists them all)"))
    return lines
