#!/usr/bin/env python3
"""The kernel's part of a live fan-out: one frame to many sockets over loopback, three ways.

    python scripts/bench/kernel_fanout.py [--receivers 50] [--frames 50] [--rounds 3] [--quick]

No WebSocket and no event loop: one process writes a real KITTI frame (2.1 MB
of GLB) to ``--receivers`` TCP connections at 10 Hz, with non-blocking
sockets and ``select``; a child process reads every connection into one
buffer. Each way of writing runs once per round, the ways interleaved:

* ``send``: ``send`` of the frame's bytes; the kernel copies them into each
  socket (what uvloop's ``transport.write`` does);
* ``sendfile``: the frame written once to a ``memfd``, then ``os.sendfile``
  to each socket, which then refers to the memfd's pages instead of copying;
* ``zerocopy``: ``send`` with ``MSG_ZEROCOPY`` (``SO_ZEROCOPY``), its
  completions read from each socket's error queue after each frame.

Reported for each: how long the writer takes to hand one frame to every
socket (from its first write to the last byte the kernel took: on loopback,
in the reader's receive queue), p50 and p99 over frames, and the CPU each
process spent per frame. This is the floor under any server's fan-out of
such frames on this machine.
"""

from __future__ import annotations

import argparse
import os
import resource
import selectors
import socket
import statistics
import time

from kit import KITTI_FRAME as FRAME
from kit import parse, percentile

WAYS = ("send", "sendfile", "zerocopy")
SO_ZEROCOPY = getattr(socket, "SO_ZEROCOPY", 60)
MSG_ZEROCOPY = getattr(socket, "MSG_ZEROCOPY", 0x4000000)


def read_all(port: int, receivers: int, total: int) -> None:
    """The reader: open ``receivers`` connections and read ``total`` bytes from them, then exit."""
    connections = [socket.create_connection(("127.0.0.1", port)) for _ in range(receivers)]
    selector = selectors.DefaultSelector()
    for connection in connections:
        connection.setblocking(False)
        selector.register(connection, selectors.EVENT_READ)
    buffer = bytearray(1 << 20)
    while total > 0:
        for key, _ in selector.select():
            try:
                total -= key.fileobj.recv_into(buffer)  # type: ignore[union-attr]
            except BlockingIOError:
                pass
    os._exit(0)


def fan_out(way: str, data: bytes, receivers: int, frames: int) -> dict[str, float]:
    """Write ``frames`` frames to ``receivers`` sockets at 10 Hz; the times and CPU per frame."""
    listener = socket.create_server(("127.0.0.1", 0), backlog=receivers)
    port = listener.getsockname()[1]
    reader = os.fork()
    if reader == 0:
        listener.close()
        read_all(port, receivers, len(data) * receivers * frames)
    connections = [listener.accept()[0] for _ in range(receivers)]
    listener.close()
    for connection in connections:
        connection.setblocking(False)
        if way == "zerocopy":
            connection.setsockopt(socket.SOL_SOCKET, SO_ZEROCOPY, 1)
    view = memoryview(data)
    size = len(data)
    selector = selectors.DefaultSelector()
    times = []
    before = resource.getrusage(resource.RUSAGE_SELF)
    for _ in range(frames):
        started = time.perf_counter()
        memfd = -1
        if way == "sendfile":
            memfd = os.memfd_create("frame")
            os.write(memfd, data)

        def write(connection: socket.socket, at: int) -> int:
            try:
                if way == "sendfile":
                    return os.sendfile(connection.fileno(), memfd, at, size - at)
                return connection.send(view[at:], MSG_ZEROCOPY if way == "zerocopy" else 0)
            except BlockingIOError:
                return 0

        pending = {}
        for connection in connections:
            at = write(connection, 0)
            if at < size:
                pending[connection] = at
                selector.register(connection, selectors.EVENT_WRITE)
        while pending:
            for key, _ in selector.select():
                connection = key.fileobj  # type: ignore[assignment]
                at = pending[connection] + write(connection, pending[connection])
                if at < size:
                    pending[connection] = at
                else:
                    del pending[connection]
                    selector.unregister(connection)
        times.append((time.perf_counter() - started) * 1000)
        if memfd >= 0:
            os.close(memfd)  # the sockets hold the pages they still send
        if way == "zerocopy":
            for connection in connections:
                try:
                    while True:
                        connection.recvmsg(0, 4096, socket.MSG_ERRQUEUE)
                except OSError:  # BlockingIOError when the queue is empty
                    pass
        time.sleep(max(0.0, started + 0.1 - time.perf_counter()))
    after = resource.getrusage(resource.RUSAGE_SELF)
    _, status, child = os.wait4(reader, 0)
    for connection in connections:
        connection.close()
    if status:
        raise RuntimeError(f"the reader failed ({status})")
    return {
        "p50": statistics.median(times),
        "p99": percentile(sorted(times), 99),
        "writer_ms": (after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime) * 1000 / frames,
        "reader_ms": (child.ru_utime + child.ru_stime) * 1000 / frames,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--receivers", type=int, default=50)
    parser.add_argument("--frames", type=int, default=50)
    parser.add_argument("--rounds", type=int, default=3)
    args = parse(parser, quick={"receivers": 5, "frames": 5, "rounds": 1})
    data = FRAME.read_bytes()
    print(
        f"{len(data) / 1e6:.1f} MB frame to {args.receivers} loopback sockets at 10 Hz, "
        f"{args.frames} frames, {args.rounds} rounds"
    )
    print(
        f"{'round':>5} {'way':>9} {'p50 ms':>7} {'p99 ms':>7} {'writer CPU ms/frame':>20} {'reader CPU ms/frame':>20}"
    )
    results: dict[str, list[dict[str, float]]] = {way: [] for way in WAYS}
    for number in range(args.rounds):
        for way in WAYS:
            result = fan_out(way, data, args.receivers, args.frames)
            results[way].append(result)
            print(
                f"{number + 1:>5} {way:>9} {result['p50']:7.1f} {result['p99']:7.1f} "
                f"{result['writer_ms']:20.1f} {result['reader_ms']:20.1f}",
                flush=True,
            )
    print("medians over rounds:")
    for way, runs in results.items():
        print(
            f"{'':>5} {way:>9} "
            + " ".join(
                f"{statistics.median(r[key] for r in runs):{width}.1f}"
                for key, width in (("p50", 7), ("p99", 7), ("writer_ms", 20), ("reader_ms", 20))
            )
        )


if __name__ == "__main__":
    main()
