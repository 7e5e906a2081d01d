"""The time-range index of a log.

A log's frames are state updates, each covering a time span ``[start, end]``
(both equal for a frame with a single timestamp). The index keeps those spans
in numpy arrays, in frame order, and answers the two questions a session asks
in O(log n): which frames fall in a time range, and which frame holds the
state at an instant.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .exceptions import DecodeError
from .layout import INDEX_FILE
from .messages import is_number

__all__ = ["TimeIndex"]


@dataclass(frozen=True, eq=False)
class TimeIndex:
    """Start and end time (seconds) of every frame, in frame order.

    Frames are assumed to be in time order, as the reference log layout
    requires; :meth:`from_spans` sorts them if they are not.
    """

    start: np.ndarray
    end: np.ndarray
    frames: np.ndarray  # frame number (message index) at each position
    # Running maximum of the end times: lets a range query binary-search the
    # first frame that reaches the range even when spans overlap.
    reach: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "reach", np.maximum.accumulate(self.end) if len(self.end) else self.end)

    @classmethod
    def from_spans(cls, spans: Iterable[tuple[float, float, int]]) -> TimeIndex:
        """Build an index from ``(start, end, frame)`` triples in any order."""
        rows = list(spans)
        return cls._in_time_order(
            np.array([row[0] for row in rows], dtype=np.float64),
            np.array([row[1] for row in rows], dtype=np.float64),
            np.array([row[2] for row in rows], dtype=np.int64),
        )

    @classmethod
    def from_reference(cls, document: Any, where: str = INDEX_FILE) -> TimeIndex:
        """Read the index file of a reference log (``0-frame.json``).

        Its ``timing`` rows are ``[t_min, t_max, message_index, name]``.
        Raises :class:`~xviz_server.exceptions.DecodeError` naming the row at
        fault.
        """
        timing = document.get("timing") if isinstance(document, dict) else None
        if not isinstance(timing, list):
            raise DecodeError(f"{where}: 'timing' must be a list of [t_min, t_max, index, name] rows")
        values = _well_formed(timing)
        if values is not None:
            return cls._in_time_order(values[:, 0], values[:, 1], values[:, 2].astype(np.int64))
        spans = []
        for row_number, row in enumerate(timing):
            if (
                not isinstance(row, Sequence)
                or len(row) < 3
                or not all(is_number(value) for value in row[:3])
                or not float(row[2]).is_integer()
                or not 0 <= row[2] < _FRAME_LIMIT
            ):
                raise DecodeError(f"{where}: timing[{row_number}] is not [t_min, t_max, index, name]: {row!r}")
            spans.append((float(row[0]), float(row[1]), int(row[2])))
        return cls.from_spans(spans)

    @classmethod
    def _in_time_order(cls, start: np.ndarray, end: np.ndarray, frames: np.ndarray) -> TimeIndex:
        order = np.lexsort((frames, start))  # by start time, then frame number
        start = start[order]
        return cls(start, np.maximum(start, end[order]), frames[order])

    @property
    def in_frame_order(self) -> bool:
        """Whether time order is frame order (times never go back from one frame to the next), as the layout requires."""
        return bool((self.frames[1:] > self.frames[:-1]).all())

    def __len__(self) -> int:
        return len(self.start)

    @property
    def start_time(self) -> float | None:
        """Start of the first frame, or ``None`` for an empty log."""
        return float(self.start[0]) if len(self) else None

    @property
    def end_time(self) -> float | None:
        """End of the last frame, or ``None`` for an empty log."""
        return float(self.reach[-1]) if len(self) else None

    def range(self, start: float | None = None, end: float | None = None) -> np.ndarray:
        """Positions of the frames overlapping ``[start, end]``, in time order.

        A missing bound means the start or end of the log. ``frames[positions]``
        gives their frame numbers.
        """
        low = 0 if start is None else int(np.searchsorted(self.reach, start, side="left"))
        high = len(self) if end is None else int(np.searchsorted(self.start, end, side="right"))
        positions = np.arange(low, max(low, high))
        if start is not None:
            positions = positions[self.end[low:high] >= start]
        return positions

    def at(self, instant: float) -> int | None:
        """Position (not frame number) of the last frame starting at or before ``instant``."""
        position = int(np.searchsorted(self.start, instant, side="right")) - 1
        return position if position >= 0 else None


#: Frame numbers are int64: the first that is not.
_FRAME_LIMIT = 2**63


def _well_formed(timing: list[Any]) -> np.ndarray | None:
    """The first three columns of ``timing`` as an (n, 3) float array, or ``None`` unless every row is valid.

    Checks a whole 100 000-row index in milliseconds, where checking row by
    row takes a second; the row-by-row check then names a row at fault.
    """
    if not all(type(row) in (list, tuple) and len(row) >= 3 for row in timing):
        return None
    head = [row[:3] for row in timing]
    if not {type(value) for row in head for value in row} <= {int, float}:
        return None
    try:
        values = np.array(head, dtype=np.float64).reshape(-1, 3)
    except OverflowError:  # an integer beyond the float range
        return None
    frames = values[:, 2]
    if not (
        np.isfinite(values).all()
        and (frames >= 0).all()
        and (frames < _FRAME_LIMIT).all()
        and (frames == np.floor(frames)).all()
    ):
        return None
    return values
