"""The live benchmarks' processes (``python -m kit.live ROLE URL ...``): a source, viewers, reference servers.

- ``source URL RATE SECONDS [OUTPUT ...]``: once the viewers writing each
  ``OUTPUT`` are connected, sends the metadata to ``URL``; once they follow
  the feed (they have the metadata), pushes a real KITTI frame (2.1 MB of
  GLB) at ``RATE`` Hz, its send time patched into the encoded frame just
  before it goes (without ``OUTPUT``, a second after the metadata);
- ``viewers URL COUNT SECONDS OUTPUT``: ``COUNT`` raw clients that read each
  frame's JSON chunk and count the rest, noting when each update's last
  byte arrives, for ``SECONDS`` from the feed's metadata; they say when
  they are connected and when they follow the feed with files beside
  ``OUTPUT`` (see :func:`signal`); the latencies go to ``OUTPUT`` as JSON;
- ``broadcast -`` and ``writes -``: the reference servers, which forward
  every message pushed to ``/ingest/...`` to every other connection.
"""

from __future__ import annotations

import asyncio
import json
import sys
import time
from pathlib import Path

import uvloop
import websockets

from kit import KITTI_FRAME as FRAME
from kit.ws import RawClient, envelope_of, forward, raw_writes

__all__ = ["ROLE", "STAMP", "READY_WITHIN", "signal", "source", "viewers", "reference_server"]

#: How a benchmark starts one of these processes (with ``cwd`` :data:`kit.proc.BENCH`).
ROLE = [sys.executable, "-m", "kit.live"]
METADATA = FRAME.with_name("1-frame.glb")

#: The send time travels in the frame as this many characters, patched into the encoded bytes.
STAMP = 16
#: Seconds the source waits for the viewers to follow its feed, and the viewers for its metadata.
READY_WITHIN = 120.0


def signal(output: str | Path, stage: str) -> Path:
    """The file that the viewers writing ``output`` make once every one of them is at ``stage``: connected, following."""
    return Path(f"{output}.{stage}")


async def _wait_for(paths: list[Path]) -> None:
    deadline = time.monotonic() + READY_WITHIN
    while not all(path.exists() for path in paths):
        if time.monotonic() > deadline:
            raise SystemExit(f"the viewers were not there within {READY_WITHIN:g} s: {[str(path) for path in paths]}")
        await asyncio.sleep(0.02)


async def source(url: str, rate: float, seconds: float, outputs: list[str]) -> None:
    from xviz_server.codec import decode_glb, encode_glb

    message = decode_glb(FRAME.read_bytes())
    sentinel = b"8" * 9 + b"." + b"8" * 6  # 15 digits: written back as read
    message["data"]["updates"][0]["timestamp"] = float(sentinel)
    frame = bytearray(encode_glb(message))  # encoded once: the source's encoding is no part of the latency
    at = frame.index(sentinel)
    async with websockets.connect(url, max_size=None, compression=None) as websocket:
        await _wait_for([signal(output, "connected") for output in outputs])
        await websocket.send(METADATA.read_bytes())
        if outputs:
            await _wait_for([signal(output, "following") for output in outputs])
        else:
            await asyncio.sleep(1.0)  # let the viewers subscribe
        start = time.perf_counter()
        for k in range(int(rate * seconds)):
            await asyncio.sleep(max(0.0, start + k / rate - time.perf_counter()))
            # perf_counter is the system's monotonic clock, the same in every process; padded with spaces (valid JSON)
            frame[at : at + STAMP] = f"{time.perf_counter():>{STAMP}.6f}".encode()
            await websocket.send(bytes(frame))


async def viewers(url: str, count: int, seconds: float, output: str) -> dict:
    """``count`` minimal WebSocket clients (``kit.ws.RawClient``) that read each frame's JSON chunk and count the rest.

    A frame's arrival is when its last byte is read; the viewers do no more
    work per frame than that, so that they measure the server, not their own
    decoding. Each watches for ``seconds`` from the first message it gets
    (the feed's metadata); see :func:`signal` for the files they make.
    """
    latencies: list[float] = []
    received = [0] * count
    size = [0]
    at = {"connected": 0, "following": 0}

    def reached(stage: str) -> None:
        at[stage] += 1
        if at[stage] == count:
            signal(output, stage).touch()

    async def view(i: int) -> None:
        viewer = await RawClient.open(url, keep=65536)
        try:
            reached("connected")
            await asyncio.wait_for(viewer.recv(), READY_WITHIN)  # the metadata: the feed is followed
            reached("following")
            deadline = time.perf_counter() + seconds
            while time.perf_counter() < deadline:
                try:
                    length, head, arrived = await asyncio.wait_for(
                        viewer.recv(), max(0.1, deadline - time.perf_counter())
                    )
                except asyncio.TimeoutError:
                    break
                if length > 100_000:
                    sent = envelope_of(head)["data"]["updates"][0]["timestamp"]
                    latencies.append((arrived - sent) * 1000)
                    received[i] += 1
                    size[0] += length
        finally:
            viewer.abort()

    await asyncio.gather(*(view(i) for i in range(count)))
    return {"latencies": latencies, "received": received, "bytes": size[0]}


async def reference_server(kind: str) -> None:
    """Forward every message from ``/ingest/...`` to every other connection.

    ``broadcast``: with ``websockets.broadcast``, the bare library. ``writes``:
    :func:`raw_writes` (what raw TCP with WebSocket framing costs: the machine's
    limit for a Python server); websockets only does the handshakes.
    """
    viewers: set = set()
    if kind == "broadcast":
        await forward(viewers, lambda message: websockets.broadcast(viewers, message))
    else:
        await forward(viewers, lambda message: raw_writes(viewers, message))


def main() -> None:
    role, url, *rest = sys.argv[1:]
    if role in ("broadcast", "writes"):
        uvloop.run(reference_server(role))
    elif role == "source":
        asyncio.run(source(url, float(rest[0]), float(rest[1]), rest[2:]))
    else:
        Path(rest[2]).write_text(json.dumps(uvloop.run(viewers(url, int(rest[0]), float(rest[1]), rest[2]))))


if __name__ == "__main__":
    main()
