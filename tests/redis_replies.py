"""Real RESP2 replies, captured byte for byte from a real redis-server, for the tests of the hand-written reader.

:func:`capture` starts Debian's ``redis-server`` on a Unix socket of its own
(no TCP port, no persistence), sends each command over a plain socket and
keeps the bytes of each reply exactly as they came, cut where hiredis says
the reply ends. The commands cover every kind of reply the broker gives:
statuses, errors, integers (negative too), nil bulk strings and arrays,
empty arrays, bulk strings small and over :data:`~xviz_server.live.redis_wire.LARGE`,
and arrays nested four deep (``XREAD``, ``XINFO STREAM FULL``, ``COMMAND INFO``).
"""

from __future__ import annotations

import shutil
import socket
import subprocess
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import hiredis

__all__ = ["capture", "command", "have_redis_server"]


def have_redis_server() -> bool:
    return shutil.which("redis-server") is not None


def command(*args: bytes) -> bytes:
    """A command as a client writes it (an array of bulk strings)."""
    return b"*%d\r\n" % len(args) + b"".join(b"$%d\r\n%s\r\n" % (len(arg), arg) for arg in args)


def _commands(frame: bytes) -> list[tuple[bytes, ...]]:
    middle = frame[: 64 * 1024 + 1]
    return [
        (b"PING",),
        (b"SET", b"k", b"v"),
        (b"GET", b"k"),
        (b"GET", b"missing"),
        (b"INCR", b"counter"),
        (b"TTL", b"missing"),  # :-2
        (b"HGET", b"k", b"f"),  # -WRONGTYPE
        (b"NOSUCHCOMMAND", b"x"),  # -ERR unknown command
        (b"LRANGE", b"missing", b"0", b"-1"),  # *0
        (b"XADD", b"feed", b"1-1", b"v", b"1", b"t", b"update", b"n", b"1", b"d", frame),
        (b"XADD", b"feed", b"1-2", b"v", b"1", b"t", b"update", b"n", b"2", b"d", middle),
        (b"XADD", b"feed", b"1-3", b"v", b"1", b"t", b"meta", b"d", b'{"version": "2.0.0"}'),
        (b"XREAD", b"COUNT", b"10", b"STREAMS", b"feed", b"0-0"),
        (b"XREAD", b"BLOCK", b"10", b"STREAMS", b"feed", b"$"),  # *-1 after the block
        (b"XRANGE", b"feed", b"-", b"+", b"COUNT", b"2"),
        (b"XREVRANGE", b"feed", b"+", b"-", b"COUNT", b"1"),
        (b"XINFO", b"STREAM", b"feed", b"FULL"),
        (b"XLEN", b"feed"),
        (b"GET", b"feed"),  # -WRONGTYPE
        (b"SET", b"big", frame),
        (b"GET", b"big"),
        (b"STRLEN", b"big"),
        (b"HSET", b"h", b"a", b"1", b"b", b"", b"c", middle),
        (b"HGETALL", b"h"),
        (b"MGET", b"k", b"missing", b"h"),
        (b"COMMAND", b"INFO", b"XADD", b"XREAD", b"GET"),
        (b"CONFIG", b"GET", b"proto-max-bulk-len"),
        (b"INFO", b"server"),
        (b"CLIENT", b"SETNAME", b"xviz-test"),
        (b"CLIENT", b"GETNAME"),
        (b"EXISTS", b"k", b"missing", b"big"),
        (b"DEL", b"big"),
    ]


def capture(frame: bytes, directory: Path | None = None) -> list[bytes]:
    """The replies of a real redis-server to the commands above, each as the bytes that came for it.

    ``frame`` is a large value (a real XVIZ frame) written and read back.
    """
    with tempfile.TemporaryDirectory(dir=directory) as folder:
        path = Path(folder) / "redis.sock"
        server = subprocess.Popen(
            [
                "redis-server",
                "--port",
                "0",
                "--unixsocket",
                str(path),
                "--save",
                "",
                "--appendonly",
                "no",
                "--dir",
                folder,
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        try:
            with _connect(path) as sock:
                return [_ask(sock, args) for args in _commands(frame)]
        finally:
            server.terminate()
            server.wait(10)


def _connect(path: Path) -> socket.socket:
    deadline = time.monotonic() + 10
    while True:
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            sock.connect(str(path))
            sock.settimeout(10)
            return sock
        except OSError:
            sock.close()
            if time.monotonic() > deadline:
                raise
            time.sleep(0.02)


def _ask(sock: socket.socket, args: Sequence[bytes]) -> bytes:
    sock.sendall(command(*args))
    reader, received = hiredis.Reader(), bytearray()
    while True:
        chunk = sock.recv(1 << 20)
        assert chunk, "redis-server closed the connection"
        received += chunk
        reader.feed(chunk)
        if reader.gets() is not False:
            return bytes(received)
