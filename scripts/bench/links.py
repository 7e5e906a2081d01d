"""Viewers on slow links: live updates a second, the longest gap, and how fast a whole log downloads, per link speed.

The viewer runs in its own network namespace behind a veth pair, the
server-to-viewer direction shaped with ``tc tbf`` (so this needs root and
``ip``/``tc``); the server serves the real KITTI frames of ``../shared/data``
both as a log and, replayed with ``--loop``, as a live feed at 10 Hz. For
each link speed and each ``--detail`` setting (``off``: every byte, as
before levels of detail; ``auto``), it reports:

* live: updates a second (of the feed's 10) and the longest gap between two,
  after the first ``warm-up`` seconds;
* log: ``transform_log`` of the whole log, as many times as fit in
  ``--log-seconds``: the seconds to the first frame, and log seconds delivered
  per second (1.0 is real time) for the first request (cut short at
  ``--log-seconds``) and the slowest later one that completed;
* the level the session ended at.

Run as root: ``python scripts/bench/links.py [--quick]``. Names in the
machine's network (``xvl<pid><letter>``, :mod:`devkit.tclink`) are removed on exit.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import subprocess
import sys
import time
from typing import Literal

from kit import KITTI  # noqa: E402  (the kit puts the repository on the path)
from devkit.tclink import TcLink, can_shape_links, tc_link

FRAME_SECONDS = 0.1  # the KITTI drive's frames are 10 Hz


# ------------------------------------------------------------------ the viewer (run in the namespace)


async def viewer(url: str, mode: str, seconds: float, warm_up: float) -> dict[str, object]:
    """What one viewer saw: live arrivals, or whole-log downloads."""
    from websockets.asyncio.client import connect

    from xviz_server.codec import decode

    result: dict[str, object] = {}
    async with connect(url, max_size=None, open_timeout=30) as websocket:
        start = time.monotonic()
        if mode == "live":
            arrivals = []
            while (now := time.monotonic() - start) < seconds:
                try:
                    data = await asyncio.wait_for(websocket.recv(), seconds - now)
                except asyncio.TimeoutError:
                    break
                if isinstance(data, bytes) and decode(data)["type"] == "xviz/state_update":
                    arrivals.append(time.monotonic() - start)
            kept = [t for t in arrivals if t >= warm_up]
            gaps = [b - a for a, b in zip([warm_up, *kept], [*kept, seconds])]
            result = {"updates_per_s": len(kept) / (seconds - warm_up), "longest_gap": max(gaps)}
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
            result = {"first_frame_s": first_frame, "first_x_real_time": speeds[0], "later_x_real_time": later and min(later)}
    return result


# ------------------------------------------------------------------ the link


async def run_viewer(link: TcLink, url: str, mode: str, seconds: float, warm_up: float) -> dict[str, object]:
    """Run :func:`viewer` in a process of its own in ``link``'s namespace; what it saw."""
    command = ["ip", "netns", "exec", link.namespace, sys.executable, __file__, "--viewer", url, mode, str(seconds), str(warm_up)]
    process = await asyncio.create_subprocess_exec(*command, stdout=subprocess.PIPE)
    stdout, _ = await process.communicate()
    return json.loads(stdout)


async def measure(link: TcLink, detail: Literal["auto", "off"], mbps: float, seconds: float, log_seconds: float) -> dict[str, object]:
    import logging

    from xviz_server.detail import START
    from xviz_server.levels import LEVELS
    from xviz_server.server import XVIZServer
    from xviz_server.settings import Settings

    levels: list[str] = []

    class Levels(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            if record.getMessage().startswith("detail changed"):
                levels.append(record.getMessage().split()[3].removeprefix("detail="))

    handler = Levels()
    logging.getLogger("xviz_server.session").addHandler(handler)
    logging.getLogger("xviz_server.session").setLevel(logging.INFO)
    settings = Settings(host=link.host, port=0, data_dir=[str(KITTI.parent)], live_from=KITTI, loop=True, detail=detail)
    try:
        async with XVIZServer(settings) as server:
            link.shape(mbps)
            base = f"ws://{link.host}:{server.port}"
            live = await run_viewer(link, f"{base}/?session_type=live&profile=default", "live", seconds, min(5.0, seconds / 3))
            start = LEVELS[START].name if detail == "auto" else "full"  # a session on a link starts one level down
            live_level = levels[-1] if levels else start
            changes = len(levels)
            log = await run_viewer(link, f"{base}/?log={KITTI.name}&profile=default", "log", log_seconds, 0)
            log_level = levels[-1] if len(levels) > changes else start
    finally:
        logging.getLogger("xviz_server.session").removeHandler(handler)
    return {"detail": detail, "mbps": mbps, **live, "live_level": live_level, **log, "log_level": log_level}


async def main(arguments: argparse.Namespace) -> None:
    if not can_shape_links():
        sys.exit("this benchmark shapes a veth pair with tc: run it as root, with ip and tc")
    rates = [20.0] if arguments.quick else arguments.mbps
    seconds = 6.0 if arguments.quick else arguments.seconds
    log_seconds = 6.0 if arguments.quick else arguments.log_seconds
    print("detail  Mbit/s  live updates/s  longest gap s  level    |  log: first frame s  x real time: first  later  level")
    with tc_link(rates[0]) as link:
        for mbps in rates:
            for detail in arguments.detail:
                r = await measure(link, detail, mbps, seconds, log_seconds)
                later = f"{r['later_x_real_time']:.2f}" if r["later_x_real_time"] else "-"
                frame = f"{r['first_frame_s']:.2f}" if r["first_frame_s"] is not None else "-"
                print(f"{detail:6}  {mbps:6g}  {r['updates_per_s']:14.1f}  {r['longest_gap']:13.2f}  {r['live_level']:7}  "
                      f"|  {frame:>17}  {r['first_x_real_time']:18.2f}  {later:>5}  {r['log_level']}", flush=True)


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--viewer":
        url, mode, seconds, warm_up = sys.argv[2], sys.argv[3], float(sys.argv[4]), float(sys.argv[5])
        print(json.dumps(asyncio.run(viewer(url, mode, seconds, warm_up))))
        sys.exit(0)
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="20 Mbit/s only, 6 s of each")
    parser.add_argument("--mbps", type=float, nargs="+", default=[100.0, 20.0, 5.0], help="link speeds")
    parser.add_argument("--seconds", type=float, default=15.0, help="seconds of live viewing per run")
    parser.add_argument("--detail", nargs="+", choices=["off", "auto"], default=["off", "auto"], help="--detail settings of the server")
    parser.add_argument("--log-seconds", type=float, default=12.0, help="seconds of log downloads per run")
    asyncio.run(main(parser.parse_args()))
