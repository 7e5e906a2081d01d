"""Which level of detail a session's link carries: measurement and choice, without I/O.

The asyncio layer samples each connection's delivery every
:data:`SAMPLE_INTERVAL` seconds on average, at jittered times (so that
the samples never keep step with the updates): how many bytes it has written so far, and
how many of those are not delivered yet (its *backlog*: the transport's
write buffer and the kernel's send queue, unsent or unacknowledged), and
how long the kernel counted the link busy with them.

A link is not known by what one frame's delivery took: a token-bucket
shaper or policer lets a burst of up to its bucket through at the speed of
the wire, so a frame smaller than the bucket arrives "at once" whatever the
rate. :class:`LinkMeter` measures the link only over spans in which it had a
queue: between two samples at least :data:`QUEUED` of whose time the link
was busy, and only when the span before was such one too (a bucket's burst
goes out at the start of a queue, in the first span). Its
:attr:`~LinkMeter.capacity` is the bytes those spans delivered over the
time the link was busy in them (as the kernel counted it, else their time); a link never found with a queue has none (it carries at least what it
carried, and nothing more is known).

:class:`DetailChooser` picks the level (:data:`~xviz_server.levels.LEVELS`)
whose bytes at the content's rate (updates a second, from the log's index
or the live feed) fit. A session whose level needs more than :data:`DOWN`
of the capacity steps down, after :data:`DOWN_AFTER` seconds (:data:`FIRST_AFTER`
if it needs more than :data:`SEVERE` times it: the link got far slower), to the most
detailed level that needs at most :data:`FIT` of what the link carried over
the last :data:`RECENT` seconds, but a live session steps down no further
than the least level that sends every update: skipping updates is a step of
its own, taken only if that level is too much and the link stayed behind,
with a backlog of more than an update, for the last :data:`RECENT` seconds
(a level that needs nearly all of a link keeps it: a capacity measured a
few percent low does not halve its updates). A step up to a level that fits a capacity
measured is taken (a log sent faster than real time keeps a queue: its
link is known); one over a link whose capacity is unknown (never found
with a queue, as with frames smaller than a bucket) is *probed* first:
the next level up is sent until :data:`PROBE_BYTES` of it were made (and then written), the
session's own level meanwhile unchanged, and it is taken only if the link
delivered those bytes at a rate, or had a queue at a rate, that it fits at
:data:`UP` of; otherwise the session stays where it is and that level is not
probed again for :data:`BACKOFF` seconds (twice as long after each failure
in a row, at most :data:`BACKOFF_MOST`). A probe starts once the level up
has seemed to fit (no queue says otherwise) for :data:`UP_AFTER` seconds.

A session on a link starts at level :data:`START`, whose first frame
arrives within half a second at 5 Mbit/s, and *climbs*: while no probe has
failed and no step down was taken, a probe comes :data:`CLIMB_AFTER` seconds
after the last change. After that, levels change at most once in
:data:`HOLD` seconds, but for a step up found too much, undone at once.
A level's bytes per update are learnt from the updates made at it; a
level not yet seen is estimated from the last one seen, scaled by their
:attr:`~xviz_server.levels.Level.share`. ``max_mbps`` caps the capacity
(a session on this host, with no link to measure, takes the level the cap
fits without a probe); a fixed level (the user's choice) is never changed.

The choice is one small object that any face of the server (the XVIZ
session, the Foxglove one) owns and feeds.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from .levels import LEVELS, Level

__all__ = [
    "Sample",
    "LinkMeter",
    "DetailChooser",
    "SAMPLE_INTERVAL",
    "WINDOW",
    "RECENT",
    "QUEUED",
    "START",
    "DOWN",
    "FIT",
    "UP",
    "SEVERE",
    "DOWN_AFTER",
    "FIRST_AFTER",
    "UP_AFTER",
    "CLIMB_AFTER",
    "HOLD",
    "PROBE_BYTES",
    "PROBE_LONGEST",
    "BACKOFF",
    "BACKOFF_MOST",
    "RATE_WINDOW",
]

#: Seconds between two samples of a connection's delivery.
SAMPLE_INTERVAL = 0.05
#: Seconds of samples the capacity is measured over.
WINDOW = 2.0
#: Seconds of samples that say what a link that got slower carries now.
RECENT = 1.0
#: Share of the time between two samples the link must have been busy for it to have had a queue then.
QUEUED = 0.8
#: Least seconds of spans with a queue a capacity is measured from (one that says a level is too much).
_LEAST_QUEUED = 0.03
#: Least seconds of them for a capacity that says a more detailed level fits (a burst may fill a span or two).
_KNOWN = 0.2
#: The level a session on a link starts at, before anything is measured (an index into the levels): one whose
#: first KITTI frame (about 50 KB) arrives well within half a second at 5 Mbit/s.
START = 4
#: A level that needs more than this share of the capacity is too much.
DOWN = 0.95
#: A level that needs more than this many times the capacity is left after :data:`FIRST_AFTER` seconds.
SEVERE = 2.0
#: Stepping down goes to the most detailed level that needs at most this share.
FIT = 0.85
#: A probed level is taken if it needs at most this share of the rate the probe found.
UP = 0.75
#: Seconds a level must have been too much before stepping down.
DOWN_AFTER = 0.6
#: Seconds the start level must have been too much for the first choice, in the first :data:`WINDOW` seconds.
FIRST_AFTER = 0.2
#: Seconds the level up must have seemed to fit before it is probed (while climbing: :data:`CLIMB_AFTER`).
UP_AFTER = 2.0
#: Seconds after a change (or the first update) that a climbing session probes the level up.
CLIMB_AFTER = 0.5
#: Least seconds between two changes of level (but for undoing a step up that was too much).
HOLD = 5.0
#: Bytes of the level up a probe writes: more than a shaper's bucket, so that a link slower than the level finds a queue.
PROBE_BYTES = 128 * 1024
#: Most seconds a probe lasts; one whose bytes were neither delivered nor found a measurable queue by then failed.
PROBE_LONGEST = 2.0
#: Seconds a level whose probe failed (or that was too much once taken) is not probed again; doubled each time in a row.
BACKOFF = 5.0
#: Most seconds of :data:`BACKOFF`.
BACKOFF_MOST = 20.0
#: Seconds after a step up in which a step down counts as that level failing (it is backed off).
_TRIAL = 10.0
#: Seconds over which a live feed's rate of updates is measured.
RATE_WINDOW = 4.0
#: Seconds of the kernel's clock tick, the least busy time it counts.
_TICK = 0.004
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
        while len(self._samples) > 3 and sample.time - self._samples[1].time >= self.window:
            self._samples.popleft()

    @property
    def capacity(self) -> float | None:
        """Bytes a second the link carried with a queue, over the window (see :meth:`capacity_over`)."""
        return self.capacity_over(self.window)

    def capacity_over(self, seconds: float, least: float = _LEAST_QUEUED) -> float | None:
        """Bytes a second the link carried while it had a queue over the last ``seconds`` (see the module);
        ``None`` while unknown: it had a queue for less than ``least`` seconds then, or carried nothing."""
        delivered, spent = 0, 0.0
        samples = list(self._samples)
        last = samples[-1].time if samples else 0.0
        before = False
        for a, b in zip(samples, samples[1:]):
            queued = self._queued(a, b)
            if queued and before and last - a.time <= seconds:
                delivered += (b.written - b.backlog) - (a.written - a.backlog)
                spent += b.busy - a.busy if a.busy is not None and b.busy is not None else b.time - a.time
            before = queued
        if spent < least or delivered <= 0:
            return None
        return delivered / spent

    def throughput(self, seconds: float) -> float | None:
        """Bytes a second delivered over the last ``seconds`` (what the link carried: a lower bound of what it
        carries); ``None`` before there are samples over half that time."""
        samples = [sample for sample in self._samples if self._samples[-1].time - sample.time <= seconds]
        if len(samples) < 2 or samples[-1].time - samples[0].time < seconds / 2:
            return None
        first, last = samples[0], samples[-1]
        return max(0, (last.written - last.backlog) - (first.written - first.backlog)) / (last.time - first.time)

    def behind(self, seconds: float, size: float) -> bool:
        """Whether the backlog stayed above ``size`` bytes for the last ``seconds`` (the link never caught up)."""
        if not self._samples or self._samples[-1].time - self._samples[0].time < seconds:
            return False
        last = self._samples[-1].time
        return all(sample.backlog > size for sample in self._samples if last - sample.time <= seconds)

    @property
    def delivered(self) -> int:
        """Bytes delivered by the last sample."""
        return self._samples[-1].written - self._samples[-1].backlog if self._samples else 0

    @staticmethod
    def _queued(a: Sample, b: Sample) -> bool:
        """Whether the link had a queue from sample ``a`` to ``b``: it was busy at least :data:`QUEUED` of the
        time, as the kernel counted it (else: both found a backlog), not waiting for the peer to read."""
        if b.reader or b.time <= a.time:
            return False
        if a.busy is not None and b.busy is not None:
            return (b.busy - a.busy) >= QUEUED * (b.time - a.time)
        return a.backlog > 0 and b.backlog > 0


@dataclass
class _Probe:
    """A level up being tried, since ``started``, when ``written`` bytes had been written and the link had been
    busy ``busy`` seconds (as the kernel counts, if it does); ``made``: bytes of updates made at the level;
    ``seen``: when bytes written after the start were first seen; ``sent``: bytes written by the end of its
    sending (``None`` while it is sent)."""

    level: Level
    started: float
    written: int
    busy: float | None
    made: int = 0
    seen: float | None = None
    sent: int | None = None


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
        #: The session's level: a session on a link starts at ``levels[START]`` (nothing is known of its link
        #: yet), a local one, or every one when turned off, at full detail.
        self.level: Level = levels[0] if local or not enabled else levels[min(START, len(levels) - 1)]
        #: Updates a second of the content (``None``: unknown, taken as 10).
        self.rate: float | None = None
        self.meter = LinkMeter()
        self._sizes: dict[str, float] = {}
        self._last_sized: Level | None = None
        self._changed_at = -math.inf
        self._went_up = False  # the last change was a step up
        self._before_up: Level | None = None  # the level it went up from
        self._climbing = True  # no probe failed and no step down was taken yet
        self._sampled_at = -math.inf
        self._first_sampled: float | None = None
        self._down_for = 0.0  # seconds the level has been too much (counted down while it is not)
        self._up_for = 0.0  # seconds the level up has seemed to fit (likewise)
        self._probe: _Probe | None = None
        self._backoff: dict[str, tuple[float, float]] = {}  # level: (not probed before, seconds of the last wait)
        self._offered: deque[tuple[float, int]] = deque()  # (time, updates a live feed offered so far)
        self._probed: float | None = None  # the rate the last probe that passed found

    @property
    def auto(self) -> bool:
        """Whether the level is chosen from the link (not fixed by the user, nor turned off)."""
        return self.enabled and self.fixed is None

    @property
    def measures(self) -> bool:
        """Whether samples of the connection's delivery can change the level: it is chosen here, for a link
        to fit or under a cap (a local session without a cap stays at full detail whatever it measures)."""
        return self.auto and (not self.local or self.cap is not None)

    @property
    def sending(self) -> Level:
        """The level updates are made at now: the session's, or the level up while a probe sends it."""
        probe = self._probe
        return probe.level if probe is not None and probe.sent is None and probe.made < PROBE_BYTES else self.level

    @property
    def estimate(self) -> float | None:
        """Bytes a second the link is taken to carry: its capacity where measured, else the rate the last probe
        that passed found, else what it carried over the window (a lower bound); ``None`` before anything."""
        return self.meter.capacity or self._probed or self.meter.throughput(self.meter.window)

    @property
    def probing(self) -> Level | None:
        """The level being probed, if a probe is under way."""
        return None if self._probe is None else self._probe.level

    def choose(self, fixed: Level | None, cap: float | None, now: float) -> Level | None:
        """The user fixed a level (``None``: auto) or a cap; the new level, if it changes at once."""
        self.fixed, self.cap = fixed, cap
        self._down_for = self._up_for = 0.0
        self._probe = None
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
        if self._probe is not None and level is self._probe.level:
            self._probe.made += size

    def offered(self, time: float, count: int, decimate: int = 1) -> None:
        """A live feed has offered the session ``count`` updates so far, at ``time``; the viewer takes every
        ``decimate``-th. Sets :attr:`rate` from the last :data:`RATE_WINDOW` seconds of them."""
        self._offered.append((time, count))
        while len(self._offered) > 2 and time - self._offered[1][0] >= RATE_WINDOW:
            self._offered.popleft()
        (t0, n0), (t1, n1) = self._offered[0], self._offered[-1]
        if t1 - t0 >= RATE_WINDOW / 2 and n1 > n0:
            self.rate = (n1 - n0) / (t1 - t0) / decimate

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
        """A sample of the connection's delivery; the session's new level, if it changes now.

        How long a condition (too much; the level up seems to fit) has held
        is counted up while it holds and down while it does not, so that a
        noisy measurement delays a change rather than prevents it.
        """
        self.meter.add(sample)
        now = sample.time
        elapsed, self._sampled_at = (0.0 if self._first_sampled is None else now - self._sampled_at), now
        if self._first_sampled is None:
            self._first_sampled = now
        if not self.auto:
            return None
        if self._probe is not None:
            return self._judge(sample)
        capacity = None if self.local else self.meter.capacity_over(self.meter.window, _KNOWN)
        budget = capacity if self.cap is None else min(capacity or math.inf, self.cap)
        need = self.need(self.level)
        if need is None:  # nothing made yet: nothing known
            self._down_for = self._up_for = 0.0
            return None
        too_much = budget is not None and need > DOWN * budget and self.level is not self._least
        if too_much and self.level is self._whole:  # only skipping updates is less: if the link fell behind
            too_much = self.meter.behind(RECENT, need / (self.rate or 10.0))
        self._down_for = self._down_for + elapsed if too_much else max(0.0, self._down_for - elapsed)
        up = self._up()
        up_need = None if up is None else self.need(up)
        fits = up_need is not None and not too_much and (budget is None or up_need <= UP * budget)
        if self.local and budget is None:
            fits = False  # no link and no cap: nothing to fit
        self._up_for = self._up_for + elapsed if fits else max(0.0, self._up_for - elapsed)
        since = now - self._changed_at
        if self._went_up and since >= _TRIAL:
            self._backoff.pop(self.level.name, None)  # taken for good: a failure later starts a new row
        first = self._changed_at == -math.inf and now - self._first_sampled < WINDOW
        severe = budget is not None and need > SEVERE * budget  # a link that got far slower: its queue grows fast
        if self._down_for >= (FIRST_AFTER if first or severe else DOWN_AFTER) and (since >= HOLD or self._went_up):
            assert budget is not None
            self._climbing = False
            if self._went_up and since < _TRIAL and self._before_up is not None:
                self._back_off(self.level, now)  # the step up was too much: undone, and not again for a while
                return self._change(self._before_up, now)
            recent = None if self.local else self.meter.capacity_over(RECENT)  # what it carries since it got slower
            return self._change(self._down_to(min(budget, recent or budget)), now)
        if up is None or not fits:
            return None
        wait = CLIMB_AFTER if self._climbing else UP_AFTER
        if self._up_for < wait or since < (CLIMB_AFTER if self._climbing else HOLD):
            return None
        if (
            capacity is not None
        ):  # the link had a queue long enough: what it carries is known, the level that fits is taken
            fitting = self._fitting(UP * min(capacity, self.cap or math.inf))
            return self._change(self.levels[min(self.levels.index(up), self.levels.index(fitting))], now, up=True)
        if self.local or up.share == self.level.share:  # no link to probe, or the same frames more often
            return self._change(up, now, up=True)
        self._probe = _Probe(up, now, sample.written, sample.busy)
        return None

    def _up(self) -> Level | None:
        """The level up from the session's, if there is one that is not backed off."""
        index = self.levels.index(self.level)
        if index == 0:
            return None
        up = self.levels[index - 1]
        until, _ = self._backoff.get(up.name, (-math.inf, 0.0))
        return None if self._sampled_at < until else up

    def _judge(self, sample: Sample) -> Level | None:
        """A sample while a probe is under way: its verdict, once there is one (the level, if taken)."""
        probe = self._probe
        assert probe is not None
        now = sample.time
        if probe.seen is None and sample.written > probe.written:
            probe.seen = now
        if probe.sent is None and probe.made >= PROBE_BYTES and sample.written - probe.written >= PROBE_BYTES:
            probe.sent = sample.written  # sent enough: the updates go back to the session's level
        capacity = self.meter.capacity_over(now - probe.started)
        need = self.need(probe.level)
        if capacity is not None and need is not None:
            if self.cap is not None:
                capacity = min(capacity, self.cap)
            if need > UP * capacity:
                self._fail(now)
                return None
        known = self.meter.capacity_over(now - probe.started, _KNOWN)
        if known is not None and probe.sent is not None:
            self._probed = known
            return self._pass(now)
        if (
            probe.sent is not None
            and self.meter.delivered >= probe.sent
            and probe.seen is not None
            and need is not None
        ):
            # delivered without a queue worth measuring: taken if the link carried it no slower than the level
            # needs, over the time it was busy with it (else, over the time it took)
            took = now - probe.seen
            if probe.busy is not None and sample.busy is not None:
                took = sample.busy - probe.busy
            took = max(_TICK, took)
            if UP * (probe.sent - probe.written) >= need * took:
                self._probed = (probe.sent - probe.written) / took
                return self._pass(now)
            self._fail(now)
            return None
        if now - probe.started >= PROBE_LONGEST:
            if sample.written == probe.written:  # nothing was sent: no verdict
                self._probe = None
                return None
            self._fail(now)
        return None

    def _pass(self, now: float) -> Level | None:
        assert self._probe is not None
        level, self._probe = self._probe.level, None
        return self._change(level, now, up=True)

    def _fail(self, now: float) -> None:
        assert self._probe is not None
        self._back_off(self._probe.level, now)
        self._probe = None
        self._climbing = False
        self._up_for = 0.0

    def _back_off(self, level: Level, now: float) -> None:
        _, last = self._backoff.get(level.name, (-math.inf, 0.0))
        wait = min(BACKOFF_MOST, 2 * last) if last else BACKOFF
        self._backoff[level.name] = (now + wait, wait)

    @property
    def _whole(self) -> Level:
        """The least detailed level that sends every update."""
        return [level for level in self.levels if level.every == 1][-1]

    @property
    def _least(self) -> Level:
        """The least detailed level there is for this session (one that skips updates only if it is live)."""
        return self.levels[-1] if self.live else self._whole

    def _down_to(self, capacity: float) -> Level:
        """The level a step down on a link of ``capacity`` goes to: the most detailed that needs at most :data:`FIT`
        of it, but no further than :attr:`_whole` from a level above it (skipping updates is a step of its own)."""
        level = self._fitting(capacity * FIT)
        if level.every > 1 and self.level is not self._whole:
            return self._whole
        return level

    def _fitting(self, budget: float) -> Level:
        """The most detailed level that needs at most ``budget`` bytes a second (the least detailed if none)."""
        for level in self.levels:
            need = self.need(level)
            if need is None or need <= budget:
                return level
            if level is self._least:
                break
        return self._least

    def _change(self, level: Level, now: float, up: bool = False) -> Level | None:
        self._down_for = self._up_for = 0.0
        if level is self.level:
            return None
        self._before_up = self.level if up else None
        self.level = level
        self._changed_at = now
        self._went_up = up
        return level
