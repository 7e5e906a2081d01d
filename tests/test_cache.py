"""The shared frame cache: byte budget, LRU order, one load per frame."""

from __future__ import annotations

import asyncio

import pytest

from xviz_server.cache import FrameCache
from xviz_server.metrics import Metrics


def loader(value: bytes, calls: list, delay: float = 0.0):
    async def load() -> bytes:
        calls.append(value)
        await asyncio.sleep(delay)
        return value

    return load


async def test_least_recently_used_frames_go_first_within_the_budget():
    metrics = Metrics()
    cache = FrameCache(250, metrics)
    calls: list = []
    for key in "abc":
        await cache.get(key, loader(key.encode() * 100, calls))
    assert len(cache) == 2 and cache.size == 200 and "a" not in cache
    await cache.get("b", loader(b"", calls))  # hit: b is now the newest
    await cache.get("d", loader(b"d" * 100, calls))
    assert "b" in cache and "c" not in cache
    sample = metrics.registry.get_sample_value
    assert sample("xviz_cache_hits_total") == 1 and sample("xviz_cache_misses_total") == 4
    assert sample("xviz_cache_evictions_total") == 2 and sample("xviz_cache_bytes") == 200


async def test_concurrent_requests_share_one_load():
    cache = FrameCache(1000, Metrics())
    calls: list = []
    results = await asyncio.gather(*(cache.get("k", loader(b"v", calls, 0.05)) for _ in range(10)))
    assert results == [b"v"] * 10 and calls == [b"v"]


async def test_a_cancelled_waiter_does_not_cancel_the_shared_load():
    cache = FrameCache(1000, Metrics())
    calls: list = []
    first = asyncio.ensure_future(cache.get("k", loader(b"v", calls, 0.1)))
    second = asyncio.ensure_future(cache.get("k", loader(b"v", calls, 0.1)))
    await asyncio.sleep(0.01)
    first.cancel()
    assert await second == b"v" and "k" in cache and len(calls) == 1


async def test_failed_loads_are_retried_and_huge_values_not_kept():
    cache = FrameCache(10, Metrics())

    async def fail() -> bytes:
        raise OSError("disk gone")

    with pytest.raises(OSError):
        await cache.get("k", fail)
    calls: list = []
    assert await cache.get("k", loader(b"ok", calls)) == b"ok" and calls == [b"ok"]
    assert await cache.get("big", loader(b"x" * 11, calls)) == b"x" * 11
    assert "big" not in cache and cache.size == 2
