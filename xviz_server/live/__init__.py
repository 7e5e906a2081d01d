"""Live feeds: sources push updates, viewers get them as they happen.

:mod:`.feed` holds the feeds and their fan-out, :mod:`.ingest` takes sources
over the network, :mod:`.replay` plays a recorded log as a feed and
:mod:`.record` writes feeds out as logs.
"""

from .feed import FeedEvent, LiveFeed, LiveRegistry, LiveUpdate, Subscription, watch_lag

__all__ = ["LiveFeed", "LiveRegistry", "LiveUpdate", "Subscription", "FeedEvent", "watch_lag"]
