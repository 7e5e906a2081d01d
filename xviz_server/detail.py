"""Which level of detail a session's link carries: measurement and choice, without I/O.

The asyncio layer samples each connection's delivery every
:data:`SAMPLE_INTERVAL` seconds on average, at jittered times (so that
the samples never keep step with the updates): how many bytes it has written so far, and
how many of those are not delivered yet (its *backlog*: the transport's
write buffer and the kernel's send queue, unsent or unacknowledged).
:class:`LinkMeter` turns the samples into the link's capacity: the bytes
delivered over the last :data:`WINDOW` seconds divided by the time the link
was busy, so that a link that is busy a tenth of the time is seen carrying
ten times what it carried. The busy time is the kernel's own count where
it tells (``TCP_INFO``'s ``tcpi_busy_time``: unbiased by when the server's
process gets the CPU to sample), else the share of samples that found a
backlog, times the window. A link seldom or never found busy is taken to be busy
three samples' worth of the window (it may have been between samples): it
carries at least some times what it carried, and a session steps up
towards full detail a few levels at a time. A backlog that waited for the
peer to read (a viewer slower than its link, seen by the kernel as a full
receive window) is not the link's: such a viewer keeps its detail.

:class:`DetailChooser` picks the level (:data:`~xviz_server.levels.LEVELS`)
whose bytes at the content's rate (updates a second, from the log's index
or the live feed) fit the capacity: a session whose level needs more than
:data:`DOWN` of the capacity steps down, after :data:`DOWN_AFTER` seconds,
to the most detailed level that needs at most :data:`FIT` of what it
carried over the last :data:`RECENT` seconds; it steps up (at most
:data:`MOST_UP` levels at once) once a more detailed level has needed at
most :data:`UP` of it for :data:`UP_AFTER` seconds. Levels change at most
once in :data:`HOLD` seconds. A session on a link starts at level
:data:`START` (one on this host at full detail), and its first choice
comes once :data:`LEAST` seconds of samples are there (a start level too
much for the link is left after :data:`FIRST_AFTER` seconds). A level's bytes per
update are learnt from the updates made at it; a level not yet seen is
estimated from the last one seen, scaled by their
:attr:`~xviz_server.levels.Level.share`. ``max_mbps`` caps the capacity; a
fixed level (the user's choice) is never changed.

The choice is one small object that any face of the server (the XVIZ
session, another protocol) can own and feed.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from .levels import LEVELS, Level

__all__ = [
    "Sample", "LinkMeter", "DetailChooser", "SAMPLE_INTERVAL", "WINDOW", "RECENT", "LEAST", "START", "DOWN", "FIT", "UP",
    "DOWN_AFTER", "FIRST_AFTER", "UP_AFTER", "HOLD", "MOST_UP",
]

#: Seconds between two samples of a connection's delivery.
SAMPLE_INTERVAL = 0.05
#: Seconds of samples the capacity is measured over.
WINDOW = 2.0
#: Seconds of samples that say what a link that got slower carries now.
RECENT = 1.0
#: Least seconds of samples a capacity is measured from (a session's first choice comes after them).
LEAST = 0.5
#: The level a session on a link starts at, before anything is measured (an index into the levels): one
#: that a few Mbit/s carry about a frame a second of, so that the first frames come soon on a slow link.
START = 1
#: A level that needs more than this share of the capacity is too much.
DOWN = 0.9
#: Stepping down goes to the most detailed level that needs at most this share.
FIT = 0.85
#: A more detailed level is taken once it needs at most this share.
UP = 0.75
#: Seconds a level must have been too much before stepping down.
DOWN_AFTER = 0.6
#: Seconds the start level must have been too much for the first choice, in the first :data:`WINDOW` seconds
#: (the start level is a guess, and the link is busy with the first frames).
FIRST_AFTER = 0.2
#: Seconds a more detailed level must have fitted before stepping up.
UP_AFTER = 2.0
#: Least seconds between two changes of level.
HOLD = 5.0
#: Most levels one step up goes.
MOST_UP = 2
#: Samples that found a link busy, at least, for its capacity to be more than a lower bound.
_BUSY_SAMPLES = 3
#: Weight of a new size in a level's running mean of bytes per update.
_SIZE_WEIGHT = 0.2


@dataclass(frozen=True)
class Sample:
    """A connection's delivery at ``time``: bytes ``written`` so far, ``backlog`` of them not yet delivered;
    ``reader``: since the sample before, the backlog waited mostly for the peer to read (its receive
    window was full), not for the link; ``busy``: seconds so far the link was busy with the connection's
    bytes (not waiting for the peer), as the kernel counts them (``None`` where it does not tell)."""

    time: float
    written: int
    backlog: int
    reader: bool = False
    busy: float | None = None


class LinkMeter:
    """The capacity of one connection's link, from its samples (see the module)."""

    def __init__(self, window: float = WINDOW) -> None:
        self.window = window
        self._samples: deque[Sample] = deque()

    def add(self, sample: Sample) -> None:
        """Take a sample (samples come in time order)."""
        self._samples.append(sample)
        while len(self._samples) > 2 and sample.time - self._samples[1].time >= self.window:
            self._samples.popleft()

    @property
    def capacity(self) -> float | None:
        """Bytes a second the link carries when busy, over the window (see :meth:`capacity_over`)."""
        return self.capacity_over(self.window)

    def capacity_over(self, seconds: float) -> float | None:
        """Bytes a second the link carried when busy over the last ``seconds``; ``None`` while unknown (the
        samples cover less than :data:`LEAST` seconds, or nothing was delivered).

        A link seldom found busy may have been busy between the samples: the
        share busy is taken to be at least three samples' worth, so that a
        link found idle is said to carry at least a few times what it carried.
        """
        samples = [sample for sample in self._samples if self._samples[-1].time - sample.time <= seconds]
        if len(samples) < 2 or samples[-1].time - samples[0].time < min(seconds, LEAST):
            return None
        first, last = samples[0], samples[-1]
        delivered = (last.written - last.backlog) - (first.written - first.backlog)
        if delivered <= 0:
            return None
        least = min(1.0, _BUSY_SAMPLES / (len(samples) - 1))
        return delivered / (last.time - first.time) / max(self._busy_share(samples), least)

    def busy(self, seconds: float = WINDOW) -> bool:
        """Whether the link was busy for at least three samples' worth of the last ``seconds``; if not, its
        capacity is a lower bound only (it may carry far more)."""
        samples = [sample for sample in self._samples if self._samples[-1].time - sample.time <= seconds]
        return len(samples) > 1 and self._busy_share(samples) * (len(samples) - 1) >= _BUSY_SAMPLES

    @staticmethod
    def _busy_share(samples: list[Sample]) -> float:
        """The share of the time between the first and the last of ``samples`` that the link was busy: as the
        kernel counted it, else the share of the samples that found a backlog not waiting for the peer."""
        first, last = samples[0], samples[-1]
        if first.busy is not None and last.busy is not None and last.time > first.time:
            return min(1.0, (last.busy - first.busy) / (last.time - first.time))
        return sum(sample.backlog > 0 and not sample.reader for sample in samples[1:]) / (len(samples) - 1)


class DetailChooser:
    """The level of detail of one session (see the module).

    ``levels`` go from the most detail to the least; ``fixed`` is a level
    chosen by the user (``None``: chosen here); ``cap`` is the most bytes a
    second the session may take (``max_mbps``); ``enabled`` false keeps
    every session at full detail; ``local``: the peer is on this host, with
    no link to fit (only a cap or a fixed level lowers its detail).
    """

    def __init__(self, levels: tuple[Level, ...] = LEVELS, *, enabled: bool = True, local: bool = False) -> None:
        self.levels = levels
        self.enabled = enabled
        self.local = local
        #: Whether updates may be skipped (a live session): a level's ``every`` divides what it needs.
        self.live = False
        self.fixed: Level | None = None
        self.cap: float | None = None
        #: The level now: a session on a link starts at ``levels[START]`` (nothing is known of its link yet),
        #: a local one, or every one when turned off, at full detail.
        self.level: Level = levels[0] if local or not enabled else levels[min(START, len(levels) - 1)]
        #: Updates a second of the content (``None``: unknown, taken as 10).
        self.rate: float | None = None
        self.meter = LinkMeter()
        self._sizes: dict[str, float] = {}
        self._last_sized: Level | None = None
        self._changed_at = -math.inf
        self._sampled_at = -math.inf
        self._first_sampled: float | None = None
        self._down_for = 0.0  # seconds the level has been too much (counted down while it is not)
        self._up_for = 0.0  # seconds a more detailed level has fitted (likewise)
        self._up_to: Level | None = None

    @property
    def auto(self) -> bool:
        """Whether the level is chosen from the link (not fixed by the user, nor turned off)."""
        return self.enabled and self.fixed is None

    @property
    def measures(self) -> bool:
        """Whether samples of the connection's delivery can change the level: it is chosen here, for a link
        to fit or under a cap (a local session without a cap stays at full detail whatever it measures)."""
        return self.auto and (not self.local or self.cap is not None)

    def choose(self, fixed: Level | None, cap: float | None, now: float) -> Level | None:
        """The user fixed a level (``None``: auto) or a cap; the new level, if it changes at once."""
        self.fixed, self.cap = fixed, cap
        self._down_for = self._up_for = 0.0
        if not self.enabled:
            return None
        if fixed is not None:
            return self._change(fixed, now)
        if cap is not None:  # a cap applies at once, from the sizes known
            target = self._fitting(cap * FIT)
            if self.levels.index(target) > self.levels.index(self.level):
                return self._change(target, now)
        return None

    def made(self, level: Level, size: int) -> None:
        """An update of ``size`` bytes was made at ``level`` for this session."""
        known = self._sizes.get(level.name)
        self._sizes[level.name] = size if known is None else known + _SIZE_WEIGHT * (size - known)
        self._last_sized = level

    def need(self, level: Level) -> float | None:
        """Bytes a second ``level`` needs at the content's rate; ``None`` before any update was made."""
        size = self._sizes.get(level.name)
        if size is None:
            seen = self._last_sized
            if seen is None:
                return None
            size = self._sizes[seen.name] * level.share / seen.share
        return size * (self.rate or 10.0) / (level.every if self.live else 1)

    def sample(self, sample: Sample) -> Level | None:
        """A sample of the connection's delivery; the new level, if it changes now.

        How long a condition (too much; a more detailed level fits) has
        held is counted up while it holds and down while it does not, so
        that a noisy measurement delays a change rather than prevents it.
        """
        self.meter.add(sample)
        now = sample.time
        elapsed, self._sampled_at = now - self._sampled_at, now
        if self._first_sampled is None:
            self._first_sampled = now
        if not self.auto:
            return None
        budget = None if self.local else self.meter.capacity
        if self.cap is not None:
            budget = self.cap if budget is None else min(budget, self.cap)
        need = self.need(self.level)
        if budget is None or need is None:  # nothing known: nothing changes
            self._down_for = self._up_for = 0.0
            return None
        # a link seldom found busy (say, before the first frame is written) is never too slow: it may carry far more
        measured = budget == self.cap or self.meter.busy()
        too_much = need > DOWN * budget and self.level is not self._least and measured
        self._down_for = self._down_for + elapsed if too_much else max(0.0, self._down_for - elapsed)
        up = self._fitting(budget * UP)  # a link seldom busy tells a lower bound only: a few levels up at a time
        up = self.levels[max(self.levels.index(up), self.levels.index(self.level) - MOST_UP)]
        if self.levels.index(up) < self.levels.index(self.level) and not too_much:
            self._up_for, self._up_to = self._up_for + elapsed, up
        else:
            self._up_for = max(0.0, self._up_for - elapsed)
        if now - self._changed_at < HOLD:
            return None
        first = self._changed_at == -math.inf and now - self._first_sampled < WINDOW
        if self._down_for >= (FIRST_AFTER if first else DOWN_AFTER):
            recent = self.meter.capacity_over(RECENT)  # what the link carries since it got slower
            return self._change(self._fitting(min(budget, recent or budget) * FIT), now)
        if self._up_for >= UP_AFTER and self._up_to is not None:
            return self._change(self._up_to, now)
        return None

    @property
    def _least(self) -> Level:
        """The least detailed level there is for this session (one that skips updates only if it is live)."""
        return self.levels[-1] if self.live else [level for level in self.levels if level.every == 1][-1]

    def _fitting(self, budget: float) -> Level:
        """The most detailed level that needs at most ``budget`` bytes a second (the least detailed if none)."""
        for level in self.levels:
            need = self.need(level)
            if need is None or need <= budget:
                return level
            if level is self._least:
                break
        return self._least

    def _change(self, level: Level, now: float) -> Level | None:
        self._down_for = self._up_for = 0.0
        self._up_to = None
        if level is self.level:
            return None
        self.level = level
        self._changed_at = now
        return level
