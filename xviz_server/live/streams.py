"""What the replicas keep in the broker (Redis), and the entries they exchange.

For each live feed, the replica that holds its source (the *owner*) keeps:

* ``xviz:reg:<name>``, a hash that expires unless renewed: ``owner`` (the
  replica's id), ``meta`` (the metadata, JSON), ``connected`` (``1`` or
  ``0``) and ``key`` (the stream id of the newest entry that is a complete
  state, where a replica that starts reading begins);
* ``xviz:updates:<name>``, a stream of :class:`Entry` (metadata, updates,
  keyframes, the source leaving), trimmed by count and bytes;
* ``xviz:control:<name>``, a short stream of ``xviz/reconfigure``
  ``config_update`` objects sent by viewers on other replicas;

and the set ``xviz:feeds`` names every feed that may be registered.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import orjson

from ..exceptions import BrokerError

__all__ = ["FEEDS", "CLAIM", "Entry", "registration", "updates", "control", "before"]

#: The set of every feed name that may be registered.
FEEDS = "xviz:feeds"
#: Version of the entries' layout; entries of another version are skipped.
VERSION = b"1"
ENTRY_KINDS = frozenset({b"meta", b"update", b"key", b"gone", b"reconfigure"})

#: Claims (or renews) a feed's registration, atomically. KEYS: registration, FEEDS, the
#: feed's stream; ARGV: replica id, time to live in ms, feed name. Returns the other
#: owner's id when another replica holds the feed, 1 when the registration is new (the
#: stream, a previous owner's, starts afresh), 0 when renewed.
CLAIM = """
local owner = redis.call('HGET', KEYS[1], 'owner')
if owner and owner ~= ARGV[1] then return owner end
if not owner then redis.call('DEL', KEYS[3]) end
redis.call('HSET', KEYS[1], 'owner', ARGV[1])
redis.call('PEXPIRE', KEYS[1], ARGV[2])
redis.call('SADD', KEYS[2], ARGV[3])
if owner then return 0 end
return 1
"""


def registration(name: str) -> str:
    return f"xviz:reg:{name}"


def updates(name: str) -> str:
    return f"xviz:updates:{name}"


def control(name: str) -> str:
    return f"xviz:control:{name}"


def before(entry_id: bytes) -> bytes:
    """The stream id just before ``entry_id``, to read from it inclusively with XREAD.

    Raises :class:`~xviz_server.exceptions.BrokerError` if ``entry_id`` is not a stream id (``<ms>-<seq>``).
    """
    ms, _, seq = entry_id.partition(b"-")
    if not ms.isdigit() or not (seq or b"0").isdigit():
        raise BrokerError(f"{entry_id[:40]!r} is not a stream id")
    if int(seq or 0) > 0:
        return b"%d-%d" % (int(ms), int(seq) - 1)
    return b"%d-%d" % (max(0, int(ms) - 1), 2**64 - 1) if int(ms) else b"0-0"


@dataclass(frozen=True)
class Entry:
    """One entry of a feed's stream.

    ``kind``: ``meta`` (``data`` is the metadata, JSON), ``update`` (``data``
    is the GLB of a state update, ``complete`` when it is a snapshot),
    ``key`` (the feed's complete state, GLB, as of update ``number``),
    ``gone`` (the source left), or, in a control stream, ``reconfigure``
    (``data`` is a viewer's ``config_update``, JSON). ``owner`` is the writing replica and
    ``number`` counts that replica's updates of the feed.
    """

    kind: bytes
    owner: bytes
    number: int = -1
    data: bytes = b""
    complete: bool = False

    def fields(self) -> dict[bytes, bytes]:
        """The entry as stream fields."""
        fields = {b"v": VERSION, b"t": self.kind, b"o": self.owner, b"n": b"%d" % self.number}
        if self.data:
            fields[b"d"] = self.data
        if self.complete:
            fields[b"c"] = b"1"
        return fields

    @classmethod
    def parse(cls, fields: Mapping[bytes, bytes]) -> Entry:
        """The entry in ``fields``; raises :class:`~xviz_server.exceptions.BrokerError` if they hold none."""
        if fields.get(b"v") != VERSION:
            raise BrokerError(f"not an entry of layout version {VERSION.decode()} (fields {sorted(fields)[:8]})")
        kind, owner, number = fields.get(b"t", b""), fields.get(b"o", b""), fields.get(b"n", b"")
        if kind not in ENTRY_KINDS or not owner or not number.lstrip(b"-").isdigit():
            raise BrokerError(f"entry with kind {kind[:20]!r}, owner {owner[:40]!r}, number {number[:20]!r}")
        data = fields.get(b"d", b"")
        if kind != b"gone" and not data:
            raise BrokerError(f"{kind.decode()} entry without data")
        return cls(kind, owner, int(number), data, fields.get(b"c") == b"1")

    def json(self) -> dict[str, Any]:
        """The JSON object held by a ``meta`` or ``reconfigure`` entry; raises :class:`~xviz_server.exceptions.BrokerError` if none."""
        try:
            value = orjson.loads(self.data)
        except orjson.JSONDecodeError as exc:
            raise BrokerError(f"{self.kind.decode()} entry that is not JSON: {exc}") from None
        if not isinstance(value, dict):
            raise BrokerError(f"{self.kind.decode()} entry holding a JSON {type(value).__name__}, not an object")
        return value
