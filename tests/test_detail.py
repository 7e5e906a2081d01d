"""The choice of a session's level of detail, fed samples of a simulated link (pure: no sockets, no clock).

The simulated link is a token bucket, as ``tc tbf`` and many shapers and
policers are: a burst of up to its bucket leaves at the speed of the wire,
the rest at its rate. The kernel's count of the time the link was busy
comes with each sample, as ``TCP_INFO`` gives it.
"""

from __future__ import annotations

import random
from dataclasses import dataclass, field

import pytest

from xviz_server.detail import HOLD, PROBE_BYTES, SAMPLE_INTERVAL, START, DetailChooser, LinkMeter, Sample
from xviz_server.levels import FULL, LEVELS

LEVEL = {level.name: level for level in LEVELS}
FULL_SIZE = 2_150_000  # bytes of a KITTI frame at full detail
MBPS = 125_000  # bytes a second in a Mbit/s
WIRE = 10_000 * MBPS  # a veth's speed
KB = 1024


@dataclass
class Link:
    """A token-bucket link carrying ``rate`` bytes a second, bursts of ``bucket`` bytes at the wire's speed, fed a
    10 Hz stream of updates at the level the chooser sends."""

    chooser: DetailChooser
    rate: float
    bucket: float = 64 * KB
    kernel: bool = True  # the kernel tells the busy time
    log: bool = False  # a log sent as fast as the link carries it (an update whenever the backlog is small)
    time: float = 0.0
    written: int = 0
    backlog: float = 0.0
    busy: float = 0.0
    tokens: float = 0.0
    changes: list[tuple[float, str]] = field(default_factory=list)
    sent: list[tuple[float, str, int]] = field(default_factory=list)  # (time, level, bytes) of each update made
    step: float = 0.001
    random: random.Random = field(default_factory=lambda: random.Random(1))
    next_sample: float = SAMPLE_INTERVAL

    def __post_init__(self) -> None:
        self.tokens = self.bucket

    def run(self, seconds: float, rate: float | None = None) -> None:
        if rate is not None:
            self.rate = rate
        end = self.time + seconds
        per_update = round(0.1 / self.step)
        while self.time < end - 1e-9:
            self.time = round(self.time + self.step, 6)
            ticks = round(self.time / self.step)
            due = self.backlog < 256 * KB if self.log else ticks % per_update == 0
            if due and self.backlog < 4 * FULL_SIZE:  # a live viewer drops when far behind
                level = self.chooser.sending
                if self.log or (ticks // per_update) % level.every == 0:
                    size = round(FULL_SIZE * level.share)
                    self.chooser.made(level, size)
                    self.sent.append((self.time, level.name, size))
                    self.written += size
                    self.backlog += size
            self.tokens = min(self.bucket, self.tokens + self.rate * self.step)
            if self.backlog > 0:
                self.busy += self.step
                out = min(self.backlog, self.tokens, WIRE * self.step)
                self.backlog -= out
                self.tokens -= out
            if self.time >= self.next_sample:  # at jittered times, as the server samples
                self.next_sample += SAMPLE_INTERVAL * self.random.uniform(0.5, 1.5)
                sample = Sample(self.time, self.written, round(self.backlog), busy=self.busy if self.kernel else None)
                changed = self.chooser.sample(sample)
                if changed is not None:
                    self.changes.append((self.time, changed.name))

    def changes_between(self, start: float, end: float) -> list[tuple[float, str]]:
        return [change for change in self.changes if start <= change[0] < end]

    def bytes_above(self, level: str, start: float = 0.0) -> int:
        """Bytes of updates made at levels more detailed than ``level`` since ``start``."""
        index = LEVELS.index(LEVEL[level])
        return sum(size for t, name, size in self.sent if t >= start and LEVELS.index(LEVEL[name]) < index)


def live_chooser() -> DetailChooser:
    chooser = DetailChooser()
    chooser.rate, chooser.live = 10.0, True
    return chooser


def test_the_first_frame_arrives_within_half_a_second_at_5_mbps():
    link = Link(live_chooser(), rate=5 * MBPS)
    assert link.chooser.level is LEVELS[START] is LEVEL["minimal"]  # nothing known yet
    link.run(0.15)
    [(_, name, size)] = link.sent
    assert name == "minimal" and size <= 0.5 * 5 * MBPS


def test_a_burst_smaller_than_the_bucket_tells_nothing_of_the_link():
    """Frames smaller than the bucket leave at the wire's speed: that is no measure of the link."""
    for bucket in (32 * KB, 64 * KB):
        meter, chooser = LinkMeter(), live_chooser()
        link = Link(chooser, rate=5 * MBPS, bucket=bucket)
        chooser.fixed = LEVEL["minimal"]  # 43 KB updates, ten a second
        link.run(5)
        capacity = chooser.meter.capacity
        assert capacity is None or capacity <= 5.5 * MBPS, (bucket, capacity)
        assert meter.capacity is None


@pytest.mark.parametrize("bucket", [32 * KB, 64 * KB, 256 * KB])
@pytest.mark.parametrize("kernel", [True, False])
def test_a_5_mbps_token_bucket_keeps_minimal_and_a_level_up_is_only_ever_probed(bucket, kernel):
    link = Link(live_chooser(), rate=5 * MBPS, bucket=bucket, kernel=kernel)
    link.run(60)
    assert link.chooser.level is LEVEL["minimal"], link.changes
    probes = [t for t, name, _ in link.sent if name != "minimal"]
    starts = [t for i, t in enumerate(probes) if i == 0 or t - probes[i - 1] > 1]
    assert len(starts) <= 5, starts  # each failure in a row waits twice as long: 5, 10, 20, 40 s
    if bucket < 256 * KB:  # a probe finds the link too slow: the level is never taken, a probe's bytes are sent
        assert link.changes == []
        assert link.bytes_above("minimal") <= len(starts) * (PROBE_BYTES + FULL_SIZE * LEVEL["low"].share), starts
    else:  # a bucket larger than a probe lets the level be taken, and undone within about a second
        ups = [t for t, level in link.changes if level == "low"]
        downs = [t for t, level in link.changes if level == "minimal"]
        assert len(ups) == len(downs) <= 4 and all(0 < down - up < 1.5 for up, down in zip(ups, downs)), link.changes


@pytest.mark.parametrize("bucket", [32 * KB, 64 * KB, 256 * KB])
def test_a_20_mbps_token_bucket_climbs_to_low_and_stays(bucket):
    link = Link(live_chooser(), rate=20 * MBPS, bucket=bucket)
    link.run(3)
    assert link.chooser.level is LEVEL["low"], link.changes
    link.run(60)
    if bucket < 256 * KB:
        assert link.changes == [(link.changes[0][0], "low")], link.changes  # medium was probed, never taken
        assert link.bytes_above("low", 3) <= 6 * FULL_SIZE * LEVEL["medium"].share
    else:  # a bucket larger than a probe: taken, and undone within about a second, less and less often
        ups = [t for t, level in link.changes if level == "medium"]
        downs = [t for t, level in link.changes[1:] if level == "low"]
        assert len(ups) == len(downs) <= 5 and all(0 < down - up < 1.5 for up, down in zip(ups, downs)), link.changes


@pytest.mark.parametrize("mbps, level", [(100, "high"), (1e4, "full")])
def test_a_fast_link_is_climbed_to_within_3_s(mbps, level):
    link = Link(live_chooser(), rate=mbps * MBPS, bucket=max(64 * KB, mbps * MBPS / 100))
    link.run(3)
    assert link.chooser.level is LEVEL[level], link.changes
    changes = len(link.changes)
    link.run(30)
    assert len(link.changes) == changes


def test_a_link_from_20_to_5_and_back_to_20_mbps():
    link = Link(live_chooser(), rate=20 * MBPS)
    link.run(10)
    assert link.chooser.level is LEVEL["low"]
    before = len(link.changes)
    link.run(2, rate=5 * MBPS)  # down within 2 s
    assert link.chooser.level is LEVEL["minimal"], link.changes
    link.run(30)  # no flapping at a steady rate
    assert link.changes_between(12, 42) == []
    link.run(22, rate=20 * MBPS)  # back up within 22 s (probes that failed at 5 Mbit/s wait up to 20 s)
    assert link.chooser.level is LEVEL["low"], link.changes
    link.run(30)
    assert link.chooser.level is LEVEL["low"]
    times = [t for t, _ in link.changes[before:]]
    assert all(b - a >= HOLD for a, b in zip(times, times[1:]))  # at most one change in 5 s


@pytest.mark.parametrize(
    "start, share, first", [("low", 0.9, "minimal"), ("minimal", 0.97, None), ("minimal", 1.3, "sparse")]
)
def test_a_live_session_skips_updates_only_if_the_link_cannot_carry_each_one(start, share, first):
    """``minimal`` needs ``share`` of the link: 90 % is more than a step down chooses, less than too much; 97 % is
    more than too much, but the link carries each update; only a link that falls behind gets ``sparse``."""
    chooser = live_chooser()
    chooser.level = LEVEL[start]  # taken on a faster link, or measured
    link = Link(chooser, rate=FULL_SIZE * LEVEL["minimal"].share * 10 / share)
    link.run(10)
    assert [name for _, name in link.changes][:1] == ([] if first is None else [first]), link.changes
    assert "sparse" not in [name for _, name in link.changes] or first == "sparse", link.changes


def test_a_session_on_this_host_keeps_full_detail_from_the_first_update():
    chooser = DetailChooser(local=True)
    chooser.rate = 10.0
    link = Link(chooser, rate=1 * MBPS)
    assert chooser.level is FULL
    link.run(10)
    assert link.changes == [] and chooser.level is FULL


def test_a_fixed_profile_is_never_changed():
    chooser = live_chooser()
    assert chooser.choose(LEVEL["medium"], None, 0.0) is LEVEL["medium"]
    link = Link(chooser, rate=1 * MBPS)
    link.run(20)
    assert link.changes == [] and chooser.level is LEVEL["medium"] and not chooser.auto
    assert chooser.choose(None, None, link.time) is None and chooser.auto  # back to auto: chosen from the link
    link.run(3)
    assert chooser.level is LEVEL["minimal"]  # then skipping updates, a step of its own: the link falls behind
    link.run(HOLD)
    assert chooser.level is LEVEL["sparse"]


def test_a_cap_applies_at_once_on_a_fast_link():
    link = Link(live_chooser(), rate=1e10)
    link.run(3)
    assert link.chooser.choose(None, 5 * MBPS, link.time) is LEVEL["minimal"]
    link.run(20)
    assert link.chooser.level is LEVEL["minimal"] and link.changes[-1][1] != "minimal"  # never up again


def test_a_cap_on_this_host_is_fitted_without_probes():
    chooser = DetailChooser(local=True)
    chooser.rate = 10.0
    link = Link(chooser, rate=1e10)
    link.run(1)
    assert chooser.choose(None, 20 * MBPS, link.time) is LEVEL["low"]
    link.run(20)
    assert chooser.level is LEVEL["low"] and chooser.probing is None


def test_turned_off_keeps_full_detail_on_any_link():
    link = Link(DetailChooser(enabled=False), rate=1 * MBPS)
    link.run(10)
    assert link.changes == [] and link.chooser.level is FULL and not link.chooser.auto
    assert link.chooser.choose(LEVEL["low"], None, 10.0) is None


def test_the_meter_measures_spans_with_a_queue_leaving_the_first_out():
    meter = LinkMeter()
    assert meter.capacity is None
    written = 0
    # a burst of 1 MB at once, then 10 s of a queue draining 1 MB a second
    for tick in range(1, 41):
        written += 50_000 if tick > 1 else 1_000_000
        meter.add(Sample(tick * 0.05, written, 500_000, busy=tick * 0.05))
    assert meter.capacity == pytest.approx(1_000_000, rel=0.01)
    idle = LinkMeter()
    for tick in range(1, 41):
        idle.add(Sample(tick * 0.05, tick * 50_000, 0, busy=tick * 0.05 / 10))
    assert idle.capacity is None and idle.throughput(2.0) == pytest.approx(1_000_000, rel=0.01)
    reader = LinkMeter()  # a backlog that waited for the peer to read is not the link's
    for tick in range(1, 41):
        reader.add(Sample(tick * 0.05, tick * 50_000, 500_000, reader=True))
    assert reader.capacity is None


def test_a_log_session_never_takes_a_level_that_only_skips_live_updates():
    chooser = DetailChooser()  # a log session: every frame is sent
    chooser.rate = 10.0
    link = Link(chooser, rate=3 * MBPS)  # too slow even for "minimal" at 10 frames a second
    link.run(5)
    assert chooser.level is LEVEL["minimal"], link.changes


def test_a_link_not_yet_busy_is_not_taken_for_a_slow_one():
    chooser = DetailChooser()  # a log session whose first frame takes long to make: only the metadata went out
    chooser.rate = 10.0
    chooser.made(chooser.level, 50_000)
    changes = [chooser.sample(Sample(tick * SAMPLE_INTERVAL, 20_000, 0, busy=0.0)) for tick in range(1, 60)]
    assert changes == [None] * 59 and chooser.level is LEVELS[START]


@pytest.mark.parametrize("mbps, level", [(5, "minimal"), (20, "low"), (100, "high")])
def test_a_log_sent_faster_than_real_time_keeps_a_queue_and_gets_its_level_at_once(mbps, level):
    chooser = DetailChooser()
    chooser.rate = 10.0
    link = Link(chooser, rate=mbps * MBPS, log=True)
    link.run(1.5)
    assert chooser.level is LEVEL[level] and len(link.changes) <= 1, link.changes
    link.run(30)
    assert chooser.level is LEVEL[level] and len(link.changes) <= 1, link.changes
