"""Viewers on slow links: live updates a second, gaps, levels over time, and how fast a whole log downloads.

The viewer runs in its own network namespace behind a veth pair, the
server-to-viewer direction shaped with ``tc tbf`` (so this needs root and
``ip``/``tc``); the server serves the real KITTI frames of ``../shared/data``
both as a log and, replayed with ``--loop``, as a live feed at 10 Hz. Links:

* ``today``: each of ``--mbps`` with a bucket of 10 ms of the rate and a
  queue of 100 ms (:func:`devkit.tclink.tc_link`'s defaults);
* ``bucket``: 20 and 5 Mbit/s with a 64 KB bucket and a 200 ms queue, as
  many shapers and policers have;
* ``changing``: the same bucket and queue, 20 Mbit/s, then 5 from a third of
  the live run, then 20 again from two thirds (watched twice ``--seconds``).

For each link, face (an XVIZ viewer, a Foxglove client subscribed to every
channel) and ``--detail`` setting it reports, for live viewing: updates a
second from the first update on, the first update's delay, the longest gap
from the first update on and counting the first (from the connection),
bytes per update, and the level over time (``minimal@0 low@1.3``: level
at seconds since the session started); and for an XVIZ viewer on a steady link,
``transform_log`` of the whole log as many times as fit in
``--log-seconds``: seconds to the first frame, log seconds delivered per
second (1.0 is real time) of the first request and of the slowest later
complete one.

Run as root: ``python scripts/bench/links.py [--quick]``. Names in the
machine's network (``xl-<pid><letter>``, :mod:`devkit.tclink`) are removed on exit.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import subprocess
import sys
import time
from dataclasses import dataclass
from typing import Literal

from kit import KITTI  # noqa: E402  (the kit puts the repository on the path)

from devkit.tclink import TcLink, can_shape_links, tc_link

FRAME_SECONDS = 0.1  # the KITTI drive's frames are 10 Hz
FOXGLOVE = "foxglove.websocket.v1"


# ------------------------------------------------------------------ the viewer (run in the namespace)


async def viewer(url: str, mode: str, seconds: float, face: str) -> dict[str, object]:
    """What one viewer saw: live arrivals, or whole-log downloads."""
    from websockets.asyncio.client import connect

    from xviz_server.codec import decode

    result: dict[str, object] = {}
    subprotocols = [FOXGLOVE] if face == FOXGLOVE else None
    async with connect(url, max_size=None, open_timeout=30, subprotocols=subprotocols) as websocket:  # type: ignore[arg-type]
        start = time.monotonic()
        if mode == "live":
            arrivals: list[tuple[float, int]] = []
            pending = 0  # bytes of a Foxglove update's messages so far
            while (now := time.monotonic() - start) < seconds:
                try:
                    data = await asyncio.wait_for(websocket.recv(), seconds - now)
                except asyncio.TimeoutError:
                    break
                if websocket.subprotocol == FOXGLOVE:  # an update: the messages before a time message
                    if isinstance(data, str):
                        message = json.loads(data)
                        if message["op"] == "advertise":
                            wanted = [
                                {"id": channel["id"], "channelId": channel["id"]} for channel in message["channels"]
                            ]
                            await websocket.send(json.dumps({"op": "subscribe", "subscriptions": wanted}))
                    elif data[0] == 0x01:
                        pending += len(data)
                    elif data[0] == 0x02 and pending:
                        arrivals.append((time.monotonic() - start, pending))
                        pending = 0
                elif isinstance(data, bytes) and decode(data)["type"] == "xviz/state_update":
                    arrivals.append((time.monotonic() - start, len(data)))
            times = [t for t, _ in arrivals]
            first_update = times[0] if times else seconds
            gaps = [b - a for a, b in zip(times, [*times[1:], seconds])]
            result = {
                "updates_per_s": (len(times) - 1) / (seconds - first_update) if len(times) > 1 else 0.0,
                "first_update_s": first_update,
                "longest_gap": max(gaps, default=seconds),
                "longest_gap_counting_first": max([first_update, *gaps]),
                "bytes_per_update": sum(n for _, n in arrivals) / max(1, len(arrivals)),
            }
        else:
            first = decode(await websocket.recv())["data"]["log_info"]["start_time"]
            speeds: list[float] = []
            complete: list[bool] = []
            first_frame = None
            while time.monotonic() - start < seconds:
                begun, last = time.monotonic(), first
                await websocket.send(json.dumps({"type": "xviz/transform_log", "data": {"id": str(len(speeds))}}))
                while True:
                    remaining = seconds - (time.monotonic() - start)
                    try:
                        message = decode(await asyncio.wait_for(websocket.recv(), max(remaining, 0.01)))
                    except asyncio.TimeoutError:
                        message = {"type": "timeout"}
                    if message["type"] == "xviz/state_update":  # log seconds delivered: up to the frame's end
                        last = message["data"]["updates"][0]["timestamp"] + FRAME_SECONDS
                        if first_frame is None:
                            first_frame = time.monotonic() - begun
                    elif message["type"] in ("xviz/transform_log_done", "timeout"):
                        speeds.append((last - first) / (time.monotonic() - begun))
                        complete.append(message["type"] != "timeout")
                        break
            later = [speed for speed, done in zip(speeds[1:], complete[1:]) if done]  # one cut short says nothing
            result = {
                "first_frame_s": first_frame,
                "first_x_real_time": speeds[0],
                "later_x_real_time": later and min(later),
            }
    return result


# ------------------------------------------------------------------ the link


@dataclass(frozen=True)
class Spec:
    """A link: its name, its rate over time ((seconds from the live run's start, Mbit/s)), bucket and queue."""

    name: str
    rates: tuple[tuple[float, float], ...]
    bucket: int | None = None
    latency: float = 0.1

    @property
    def steady(self) -> bool:
        return len(self.rates) == 1


async def run_viewer(link: TcLink, url: str, mode: str, seconds: float, face: str) -> dict[str, object]:
    """Run :func:`viewer` in a process of its own in ``link``'s namespace; what it saw."""
    command = [
        "ip",
        "netns",
        "exec",
        link.namespace,
        sys.executable,
        __file__,
        "--viewer",
        url,
        mode,
        str(seconds),
        face,
    ]
    process = await asyncio.create_subprocess_exec(*command, stdout=subprocess.PIPE)
    stdout, _ = await process.communicate()
    return json.loads(stdout)


async def reshape(link: TcLink, rates: tuple[tuple[float, float], ...], session: asyncio.Event) -> None:
    """Change ``link``'s rate at the times ``rates`` give (from the start of the ``session``)."""
    await session.wait()
    start = time.monotonic()
    for at, mbps in rates[1:]:
        await asyncio.sleep(max(0.0, at - (time.monotonic() - start)))
        link.shape(mbps)


async def measure(
    spec: Spec, face: str, detail: Literal["auto", "off"], seconds: float, log_seconds: float
) -> dict[str, object]:
    import logging

    from xviz_server.detail import START
    from xviz_server.levels import LEVELS
    from xviz_server.server import XVIZServer
    from xviz_server.settings import Settings

    levels: list[tuple[float, str]] = []
    started: list[float] = []
    session = asyncio.Event()

    class Levels(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            if record.getMessage().startswith("detail changed"):
                levels.append((record.created, record.getMessage().split()[3].removeprefix("detail=")))
            elif record.getMessage().startswith("session start") and not started:
                started.append(record.created)
                session.set()

    handler = Levels()
    logging.getLogger("xviz_server.session").addHandler(handler)
    logging.getLogger("xviz_server.session").setLevel(logging.INFO)
    settings = Settings(host="0.0.0.0", port=0, data_dir=[str(KITTI.parent)], live_from=KITTI, loop=True, detail=detail)
    start_level = LEVELS[START].name if detail == "auto" else "full"  # a session on a link starts low
    try:
        with tc_link(spec.rates[0][1], latency=spec.latency, bucket=spec.bucket, prefix="xl-") as link:
            async with XVIZServer(settings.model_copy(update={"host": link.host})) as server:
                base = f"ws://{link.host}:{server.port}"
                changing = asyncio.ensure_future(reshape(link, spec.rates, session))
                watched = seconds if spec.steady else 2 * seconds
                live = await run_viewer(link, f"{base}/?session_type=live&profile=default", "live", watched, face)
                changing.cancel()
                began = started[0] if started else time.time()
                over_time = [(0.0, start_level)] + [(round(t - began, 1), name) for t, name in levels]
                live["levels"] = " ".join(f"{name}@{t:g}" for t, name in over_time)
                log: dict[str, object] = {}
                if face == "xviz" and spec.steady:
                    link.shape(spec.rates[0][1])
                    log = await run_viewer(link, f"{base}/?log={KITTI.name}&profile=default", "log", log_seconds, face)
    finally:
        logging.getLogger("xviz_server.session").removeHandler(handler)
    return {"link": spec.name, "face": "foxglove" if face == FOXGLOVE else "xviz", "detail": detail, **live, **log}


def specs(arguments: argparse.Namespace) -> list[Spec]:
    third = arguments.seconds * 2 / 3  # a changing link is watched twice as long: a third of it at each rate
    found = [Spec(f"today {mbps:g}", ((0.0, mbps),)) for mbps in arguments.mbps]
    found += [Spec(f"bucket {mbps:g}", ((0.0, mbps),), 64_000, 0.2) for mbps in (20.0, 5.0)]
    found.append(Spec("changing 20-5-20", ((0.0, 20.0), (third, 5.0), (2 * third, 20.0)), 64_000, 0.2))
    return [spec for spec in found if arguments.links is None or spec.name.split()[0] in arguments.links]


async def main(arguments: argparse.Namespace) -> None:
    if not can_shape_links():
        sys.exit("this benchmark shapes a veth pair with tc: run it as root, with ip and tc")
    if arguments.quick:
        arguments.mbps, arguments.seconds, arguments.log_seconds = [20.0], 6.0, 6.0
    print(
        "link              face      detail  updates/s  first s  gap s  gap+first s  bytes/update  |  log: first s  first x  later x  |  levels"
    )
    for spec in specs(arguments):
        for face in arguments.faces:
            for detail in arguments.detail:
                r = await measure(
                    spec, FOXGLOVE if face == "foxglove" else "xviz", detail, arguments.seconds, arguments.log_seconds
                )
                log = "           -        -        -"
                if "first_x_real_time" in r:
                    later = f"{r['later_x_real_time']:.2f}" if r["later_x_real_time"] else "-"
                    frame = f"{r['first_frame_s']:.2f}" if r["first_frame_s"] is not None else "-"
                    log = f"{frame:>13}  {r['first_x_real_time']:7.2f}  {later:>7}"
                print(
                    f"{spec.name:16}  {r['face']:8}  {detail:6}  {r['updates_per_s']:9.1f}  {r['first_update_s']:7.2f}  "
                    f"{r['longest_gap']:5.2f}  {r['longest_gap_counting_first']:11.2f}  {r['bytes_per_update']:12.0f}  |  {log}  |  "
                    f"{r['levels']}",
                    flush=True,
                )


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--viewer":
        url, mode, seconds, face = sys.argv[2], sys.argv[3], float(sys.argv[4]), sys.argv[5]
        print(json.dumps(asyncio.run(viewer(url, mode, seconds, face))))
        sys.exit(0)
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="today's 20 Mbit/s and the others, 6 s of each")
    parser.add_argument("--mbps", type=float, nargs="+", default=[100.0, 20.0, 5.0], help="today's link speeds")
    parser.add_argument(
        "--links", nargs="+", choices=["today", "bucket", "changing"], help="which kinds of link (default: all)"
    )
    parser.add_argument(
        "--faces", nargs="+", choices=["xviz", "foxglove"], default=["xviz", "foxglove"], help="viewers"
    )
    parser.add_argument("--seconds", type=float, default=15.0, help="seconds of live viewing per run")
    parser.add_argument(
        "--detail", nargs="+", choices=["off", "auto"], default=["auto"], help="--detail settings of the server"
    )
    parser.add_argument("--log-seconds", type=float, default=12.0, help="seconds of log downloads per run")
    asyncio.run(main(parser.parse_args()))
