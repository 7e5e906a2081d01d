"""A live feed's updates as Foxglove messages, converted once per update for every Foxglove client of the feed.

A feed's channels are those :func:`~xviz_server.foxglove.translate.plan`
gives for its metadata (:func:`feed_plan`, made once per metadata). Each
update's messages are :func:`~xviz_server.foxglove.translate.convert` of its
GLB bytes, made by the first Foxglove client to ask and kept with the update
(:meth:`~xviz_server.live.LiveUpdate.derived`): the other clients of the
feed get the same bytes. Below full detail they are made of the update's
encoding at that level, the one XVIZ viewers at the level are sent.
"""

from __future__ import annotations

import asyncio
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any
from weakref import WeakKeyDictionary

from ..levels import FULL, Level
from ..live import LiveFeed, LiveUpdate
from ..work import Workers
from .translate import CONVERTED, Plan, convert, first_origin, nanoseconds, plan

__all__ = ["LivePlan", "feed_plan", "converted", "update_time"]


@dataclass(frozen=True, eq=False)
class LivePlan:
    """A feed's Foxglove channels under one metadata (compared and hashed by identity: one per metadata)."""

    metadata: Mapping[str, Any]
    plan: Plan


_plans: WeakKeyDictionary[LiveFeed, LivePlan] = WeakKeyDictionary()


def feed_plan(feed: LiveFeed, update: LiveUpdate | None = None) -> LivePlan | None:
    """The channels of ``feed`` under its current metadata, or ``None`` before it has any.

    The feed's origin (where ``map`` is) is the first ``map_origin`` of the
    first ``update`` that has one under this metadata: from then on every
    client of the feed gets the same plan.
    """
    metadata = feed.metadata
    if metadata is None:
        return None
    held = _plans.get(feed)
    if held is None or held.metadata is not metadata:
        held = _plans[feed] = LivePlan(metadata, plan(metadata))
    if update is not None and held.plan.origin is None:
        origin = first_origin(update.message["data"]["updates"])
        if origin is not None:
            held = _plans[feed] = LivePlan(metadata, replace(held.plan, origin=origin))
    return held


async def converted(update: LiveUpdate, channels: LivePlan, workers: Workers, level: Level = FULL) -> bytes:
    """The Foxglove messages of ``update`` at ``level`` of detail on ``channels``, packed
    (:func:`~xviz_server.records.pack`).

    Raises :class:`~xviz_server.exceptions.DecodeError` for an update that
    cannot be converted (one of its updates has no timestamp).
    """
    return await asyncio.shield(
        update.derived((CONVERTED, channels), convert, channels.plan, workers=workers, level=level)
    )


def update_time(update: LiveUpdate) -> int | None:
    """The time of ``update`` in nanoseconds: its newest XVIZ timestamp (``None`` if it has none)."""
    stamps = [item.get("timestamp") for item in update.message["data"]["updates"] if isinstance(item, dict)]
    numbers = [stamp for stamp in stamps if isinstance(stamp, (int, float)) and not isinstance(stamp, bool)]
    return nanoseconds(max(numbers)) if numbers else None
