"""The choice of a session's level of detail, fed samples of a simulated link (pure: no sockets, no clock)."""

from __future__ import annotations

import random
from dataclasses import dataclass, field

import pytest

from xviz_server.detail import HOLD, SAMPLE_INTERVAL, START, DetailChooser, LinkMeter, Sample
from xviz_server.levels import FULL, LEVELS

LEVEL = {level.name: level for level in LEVELS}
FULL_SIZE = 2_150_000  # bytes of a KITTI frame at full detail
MBPS = 125_000  # bytes a second in a Mbit/s


@dataclass
class Link:
    """A link carrying ``rate`` bytes a second, fed a 10 Hz stream of updates at the chooser's level."""

    chooser: DetailChooser
    rate: float
    time: float = 0.0
    written: int = 0
    backlog: float = 0.0
    changes: list[tuple[float, str]] = field(default_factory=list)
    step: float = 0.005
    random: random.Random = field(default_factory=lambda: random.Random(1))
    next_sample: float = SAMPLE_INTERVAL

    def run(self, seconds: float, rate: float | None = None) -> None:
        if rate is not None:
            self.rate = rate
        end = self.time + seconds
        while self.time < end - 1e-9:
            self.time = round(self.time + self.step, 6)
            ticks = round(self.time / self.step)
            if ticks % round(0.1 / self.step) == 0 and self.backlog < 4 * FULL_SIZE:  # a live viewer drops when far behind
                level = self.chooser.level
                if (ticks // round(0.1 / self.step)) % level.every == 0:
                    size = round(FULL_SIZE * level.share)
                    self.chooser.made(level, size)
                    self.written += size
                    self.backlog += size
            self.backlog = max(0.0, self.backlog - self.rate * self.step)
            if self.time >= self.next_sample:  # at jittered times, as the server samples
                self.next_sample += SAMPLE_INTERVAL * self.random.uniform(0.5, 1.5)
                changed = self.chooser.sample(Sample(self.time, self.written, round(self.backlog)))
                if changed is not None:
                    self.changes.append((self.time, changed.name))

    def changes_between(self, start: float, end: float) -> list[tuple[float, str]]:
        return [change for change in self.changes if start <= change[0] < end]


def live_chooser() -> DetailChooser:
    chooser = DetailChooser()
    chooser.rate, chooser.live = 10.0, True
    return chooser


def test_a_session_on_a_link_starts_one_level_down_and_a_fast_link_gets_full_detail_within_3_s():
    link = Link(live_chooser(), rate=1e9)
    assert link.chooser.level is LEVELS[START] is LEVEL["high"]  # nothing known yet: the first frames come soon
    link.run(30)
    [(when, level)] = link.changes
    assert level == "full" and when <= 3 and link.chooser.level is FULL


def test_a_session_on_this_host_keeps_full_detail_from_the_first_update():
    chooser = DetailChooser(local=True)
    chooser.rate = 10.0
    link = Link(chooser, rate=1 * MBPS)
    assert chooser.level is FULL
    link.run(10)
    assert link.changes == [] and chooser.level is FULL


@pytest.mark.parametrize("mbps, level", [(100, "high"), (20, "low"), (5, "minimal")])
def test_a_slow_link_gets_the_level_it_carries_within_a_second_and_keeps_it(mbps, level):
    link = Link(live_chooser(), rate=mbps * MBPS)
    link.run(1)  # the start level is a guess: left as soon as it is seen too much
    assert link.chooser.level is LEVEL[level], link.changes
    link.run(60)
    assert len(link.changes) == (level != LEVELS[START].name)  # one change at most, the first choice


def test_a_link_dropping_from_100_to_5_mbps_then_recovering():
    link = Link(live_chooser(), rate=100 * MBPS)
    link.run(20)
    assert link.chooser.level is LEVEL["high"]
    before = len(link.changes)
    link.run(2, rate=5 * MBPS)  # down within 2 s
    assert link.chooser.level is LEVEL["minimal"], link.changes
    link.run(40)  # no flapping at a steady rate
    assert len(link.changes_between(25, 62)) == 0
    link.run(10, rate=100 * MBPS)  # back up within 10 s
    assert link.chooser.level is LEVEL["high"], link.changes
    link.run(30)
    assert link.chooser.level is LEVEL["high"]
    times = [t for t, _ in link.changes[before:]]
    assert all(b - a >= HOLD for a, b in zip(times, times[1:]))  # at most one change in 5 s


def test_a_fixed_profile_is_never_changed():
    chooser = live_chooser()
    assert chooser.choose(LEVEL["medium"], None, 0.0) is LEVEL["medium"]
    link = Link(chooser, rate=1 * MBPS)
    link.run(20)
    assert link.changes == [] and chooser.level is LEVEL["medium"] and not chooser.auto
    assert chooser.choose(None, None, link.time) is None and chooser.auto  # back to auto: chosen from the link
    link.run(3)
    assert chooser.level is LEVEL["sparse"]


def test_a_cap_applies_at_once_on_a_fast_link():
    link = Link(live_chooser(), rate=1e9)
    link.run(2)
    assert link.chooser.choose(None, 5 * MBPS, link.time) is LEVEL["minimal"]
    link.run(20)
    assert link.chooser.level is LEVEL["minimal"] and link.changes == []


def test_turned_off_keeps_full_detail_on_any_link():
    link = Link(DetailChooser(enabled=False), rate=1 * MBPS)
    link.run(10)
    assert link.changes == [] and link.chooser.level is FULL and not link.chooser.auto
    assert link.chooser.choose(LEVEL["low"], None, 10.0) is None


def test_the_meter_measures_a_link_busy_part_of_the_time():
    meter = LinkMeter()
    assert meter.capacity is None
    written = 0
    for tick in range(1, 41):  # 2 s; a quarter of the samples find a backlog, 1 MB delivered a second
        written += 50_000
        meter.add(Sample(tick * 0.05, written, 1000 if tick % 4 == 0 else 0))
    assert meter.capacity == pytest.approx(4_000_000, rel=0.1)
    kernel = LinkMeter()  # the kernel counts a quarter of the time busy; every sample happened to find a backlog
    for tick in range(1, 41):
        kernel.add(Sample(tick * 0.05, tick * 50_000, 1000, busy=tick * 0.05 / 4))
    assert kernel.capacity == pytest.approx(4_000_000, rel=0.1) and kernel.busy()
    idle = LinkMeter()
    for tick in range(1, 41):
        idle.add(Sample(tick * 0.05, 0, 0))
    assert idle.capacity is None  # nothing delivered: nothing known


def test_a_log_session_never_takes_a_level_that_only_skips_live_updates():
    chooser = DetailChooser()  # a log session: every frame is sent
    chooser.rate = 10.0
    link = Link(chooser, rate=3 * MBPS)  # too slow even for "minimal" at 10 frames a second
    link.run(5)
    assert chooser.level is LEVEL["minimal"], link.changes


def test_a_link_seldom_busy_is_stepped_up_at_most_two_levels_at_once():
    link = Link(live_chooser(), rate=5 * MBPS)
    link.run(20)
    chooser, written, time = link.chooser, link.written, link.time
    assert chooser.level is LEVEL["minimal"]
    changes = []
    for _ in range(200):  # 10 s of a link never found busy that delivered 20 MB a second: it may carry anything
        time, written = time + SAMPLE_INTERVAL, written + 1_000_000
        if (changed := chooser.sample(Sample(time, written, 0))) is not None:
            changes.append(changed.name)
    assert changes == ["medium", "full"]


def test_a_link_not_yet_busy_is_not_taken_for_a_slow_one():
    chooser = DetailChooser()  # a log session whose first frame takes long to make: only the metadata went out
    chooser.rate = 10.0
    chooser.made(chooser.level, 760_000)
    changes = [chooser.sample(Sample(tick * SAMPLE_INTERVAL, 20_000 if tick > 1 else 0, 0)) for tick in range(1, 60)]
    assert changes == [None] * 59 and chooser.level is LEVELS[START]
