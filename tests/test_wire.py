"""The hand-written RESP2 reader of the broker's wire (``live/redis_wire.py``), without a server process or the KITTI data.

The reader is sans I/O: bytes go in as the socket splits them, whole replies
come out. Here it is held to hiredis, the C parser redis-py uses, on real
replies captured from a real ``redis-server`` (see ``redis_replies.py``)
and split at random: after every read both must have produced the same
replies. The tests that need a server start one on a Unix socket of its own.
"""

from __future__ import annotations

import itertools
import random
import re
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from redis_replies import capture, have_redis_server

from xviz_server.codec import encode_glb

hiredis = pytest.importorskip("hiredis", reason="needs the broker extra: pip install -e '.[broker]'")
from redis.exceptions import InvalidResponse, ResponseError  # noqa: E402  (after the broker extra is known)

from xviz_server.live.redis_wire import LARGE, Replies  # noqa: E402

needs_server = pytest.mark.skipif(not have_redis_server(), reason="needs redis-server: run scripts/test.sh")


def large_frame() -> bytes:
    """A 2.4 MB GLB state update of a random point cloud: a bulk string whose bytes hold CRLF and RESP type bytes."""
    points = np.random.default_rng(7).uniform(-80, 80, (200_000, 3)).astype(np.float32)
    return encode_glb(
        {
            "type": "xviz/state_update",
            "data": {
                "update_type": "SNAPSHOT",
                "updates": [{"timestamp": 1.5, "primitives": {"/lidar": {"points": [{"points": points}]}}}],
            },
        }
    )


@pytest.fixture(scope="module")
def replies() -> list[bytes]:
    return capture(large_frame())


def parse(data: bytes, sizes: Iterator[int]) -> list[Any]:
    """``data`` put in a :class:`Replies` buffer in reads of ``next(sizes)`` bytes (at most what it offers)."""
    return [reply for _, batch in reads(data, sizes) for reply in batch]


def reads(data: bytes, sizes: Iterator[int]) -> Iterator[tuple[bytes, list[Any]]]:
    """Each read of ``data`` into a :class:`Replies` (``next(sizes)`` bytes, or what its buffer offers) and the replies it completed."""
    replies, at = Replies(), 0
    while at < len(data):
        room = replies.buffer()
        assert len(room) > 0
        count = min(len(room), next(sizes), len(data) - at)
        room[:count] = data[at : at + count]
        at += count
        yield data[at - count : at], replies.received(count)


def same(value: Any) -> Any:
    """A reply with its error replies as ``("error", text)``, whichever parser made them."""
    if isinstance(value, list):
        return [same(item) for item in value]
    if isinstance(value, Exception):
        return ("error", str(value))
    return value


@needs_server
def test_real_replies_split_at_random_parse_as_hiredis_parses_them(replies: list[bytes]):
    stream = b"".join(replies)
    assert len(replies) > 30 and any(len(reply) > LARGE for reply in replies)
    rng = random.Random(33)
    splits: list[tuple[Iterator[int], int]] = [  # the reads' sizes, and how many replies to compare
        (itertools.repeat(len(stream)), len(replies)),
        (itertools.repeat(1), 12),  # a byte at a time: the first replies are enough
        (itertools.cycle([1, 2, 3, 5, 8, 13]), 13),
        (iter(lambda: rng.randint(1, 300_000), None), len(replies)),
        (iter(lambda: rng.choice([1, 2, rng.randint(1, 200), rng.randint(1, 5_000_000)]), None), len(replies)),
    ]
    for sizes, enough in splits:
        reader, mine, theirs = hiredis.Reader(), [], []
        for chunk, batch in reads(stream, sizes):
            reader.feed(chunk)
            while (reply := reader.gets()) is not False:
                theirs.append(same(reply))
            mine += [same(reply) for reply in batch]
            assert len(mine) == len(theirs)  # no reply held back, none made up
            if len(mine) >= enough:
                break
        assert len(mine) == enough and mine == theirs
    for reply in replies:  # each reply alone, in two parts cut at every tenth of it
        for cut in {len(reply) * k // 10 for k in range(1, 10)} - {0}:
            assert same(parse(reply, itertools.chain([cut], itertools.repeat(len(reply))))) == [same(_one(reply))]


def _one(reply: bytes) -> Any:
    reader = hiredis.Reader()
    reader.feed(reply)
    return reader.gets()


def test_replies_come_out_whole_however_the_socket_splits_them():
    frame = large_frame()[:300_000]  # over LARGE: read into a buffer of its own; short enough to feed a byte at a time
    small, shorter = frame[: LARGE - 7], frame[-LARGE - 100 :]  # the second large one is read where the first was
    stream = (
        b"+OK\r\n-ERR wrong number of arguments\r\n:42\r\n$-1\r\n*-1\r\n*0\r\n$0\r\n\r\n"
        + b"*1\r\n*2\r\n$1\r\ns\r\n*2\r\n*2\r\n$3\r\n1-0\r\n*2\r\n$1\r\nd\r\n$%d\r\n%s\r\n" % (len(frame), frame)
        + b"*2\r\n$3\r\n2-0\r\n*2\r\n$1\r\nd\r\n$%d\r\n%s\r\n" % (len(small), small)
        + b":-7\r\n$%d\r\n%s\r\n" % (len(shorter), shorter)
    )
    rng = random.Random(21)
    for sizes in [
        itertools.repeat(len(stream)),
        itertools.repeat(1),
        itertools.cycle([2, 3, 5, 7]),
        itertools.repeat(65_536),
        iter(lambda: rng.randint(1, 300_000), None),
    ]:
        replies = parse(stream, sizes)
        assert (
            replies[0] == b"OK"
            and isinstance(replies[1], ResponseError)
            and str(replies[1]) == "ERR wrong number of arguments"
        )
        assert replies[2:7] == [42, None, None, [], b""]
        assert replies[7] == [[b"s", [[b"1-0", [b"d", frame]], [b"2-0", [b"d", small]]]]] and replies[8] == -7
        assert replies[9] == shorter and len(replies) == 10
        assert all(type(value) is bytes for value in (replies[7][0][1][0][1][1], replies[7][0][1][1][1][1], replies[9]))


@pytest.mark.parametrize(
    "data, problem",
    [
        (b"!oops\r\n", "not a RESP2 reply from the broker: b'!oo"),  # refused at its first byte
        (b"$5\r\nabcdefg\r\n", "does not end where its length says"),
        (b"$70000\r\n" + b"x" * 70_001 + b"\r\n", "does not end where its length says"),
        (b"$-5\r\n", "a length of -5"),
        (b"*x\r\n", "not an integer from the broker: b'x'"),
        (b"$%d\r\n" % (2**40), "a bulk string of 1099511627776 bytes from the broker (at most 536870912)"),
        (b"+" + b"a" * 200_000, "a line of over 65536 bytes"),
        (b"*1\r\n" * 17 + b":1\r\n", "a reply of arrays nested over 16 deep"),
    ],
)
def test_what_is_not_resp_is_refused_by_name(data: bytes, problem: str):
    for sizes in [itertools.repeat(len(data)), itertools.repeat(3)]:
        with pytest.raises(InvalidResponse, match=re.escape(problem)):
            parse(data, sizes)
