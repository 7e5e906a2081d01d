"""The catalog at fleet scale: 100 000 logs listed, searched and restarted (issues 31 and 39).

    python scripts/bench/catalog.py [--logs 100000] [--quick] [--requests 200] [--fleet indexed|unindexed]

Makes two fleets of small logs in the reference layout (``devkit/fleet.py``'s
``write_fleet``: JSON metadata and two frames hard-linked from one log; the
*indexed* fleet's logs have an index document, the *unindexed* fleet's have
none, as fleets are often written) once each, under ``--fleet-dir`` (kept for
the next run), with every folder an hour old, as a fleet store holds them.
Then, for each fleet (``--fleet`` runs one), it runs the server
(``xviz-server serve``, a process of its own, on loopback) over it and
measures:

* the first build of the catalog: from the start of the process to every log
  indexed (``indexed == found`` in ``GET /api/logs``), with the CPU time
  (user + system) the server and its worker processes took to it, which the
  load changes less than the wall time;
* the first page (``GET /api/logs``, 100 logs) and a filtered search (a name
  substring and a one-hour time range, different each request), p50 and p95
  over ``--requests`` sequential requests, against ``GET /healthz`` on the same
  server (the reference: HTTP on the same port, no catalog);
* a restart with its catalog: from the start of the process to listening, and
  to the first page answered, with the CPU time the process took to listen;
  against the same server over an empty data directory and ``python -c pass``
  (the interpreter's own start), both in the same run;
* a log copied in while serving (into a hidden folder, then renamed into
  place): seconds until ``GET /api/logs/NAME`` has it;
* the server's RSS with the catalog built and the requests served, and its
  peak RSS, against the same server over an empty data directory once it is
  ready for sessions; and the worker processes' RSS then.

``--quick`` is 2 000 logs and 50 requests: a few seconds once the fleet exists.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import socket
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

from kit.proc import cpu_seconds, descendants, free_port, rss_mib

from devkit.fleet import FLEET_START, write_fleet

REPO = Path(__file__).resolve().parents[2]


def make_fleet(directory: Path, count: int, index: bool) -> None:
    """``count`` logs in ``directory``, made once (a marker file says the fleet is whole; an interrupted one is finished).

    Every folder is then set an hour old, as a fleet store's logs are (a log
    folder without an index waits until it has not changed for a while).
    """
    marker = directory / ".complete"
    if marker.exists():
        return
    started = time.perf_counter()
    step = 5000  # each step's frames link to a log of its own: a file system allows some 65 000 links to a file
    for start in range(0, count, step):
        size = min(step, count - start)
        names = [f"car-{i % 100:02d}/seg-{i:06d}" for i in range(start, start + size)]
        if (directory / names[-1] / "3-frame.json").exists():
            continue
        for name in names:
            shutil.rmtree(directory / name, ignore_errors=True)
        source = directory / ".frames" / str(start)
        shutil.rmtree(source, ignore_errors=True)
        (first,) = write_fleet(source, 1, cars=1)
        write_fleet(directory, size, cars=100, first=start, frames_from=source / first.name, index=index)
    long_ago = time.time() - 3600
    for folder, _, _ in os.walk(directory):
        os.utime(folder, (long_ago, long_ago))
    marker.write_text(str(count))
    print(f"made {count} logs in {directory} in {time.perf_counter() - started:.0f} s", flush=True)


class Server:
    """``xviz-server serve`` in a process of its own."""

    def __init__(self, data: Path, state: Path) -> None:
        self.port = free_port()
        self.started = time.perf_counter()
        self.process = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "xviz_server",
                "serve",
                "--data-dir",
                str(data),
                "--state-dir",
                str(state),
                "--port",
                str(self.port),
                "--host",
                "127.0.0.1",
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            cwd=REPO,
        )

    def wait_listening(self) -> float:
        """Seconds from the start of the process to a TCP connection accepted."""
        while True:
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=1).close()
                listening = time.perf_counter() - self.started
                fields = Path(f"/proc/{self.process.pid}/stat").read_text().rpartition(")")[2].split()
                self.cpu = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # user + system, to listening
                return listening
            except OSError:
                if self.process.poll() is not None:
                    raise RuntimeError("the server exited") from None
                time.sleep(0.005)

    def wait_ready(self) -> None:
        """Until the server is ready for sessions (it listens before): ``/healthz`` answers only then."""
        self.get("/healthz")

    def get(self, path: str) -> Any:
        with urllib.request.urlopen(f"http://127.0.0.1:{self.port}{path}", timeout=60) as response:
            body = response.read()
        return json.loads(body) if response.headers["Content-Type"] == "application/json" else body

    def rss_mb(self, field: str = "VmRSS") -> float:
        """The server's RSS (``VmHWM``: its peak so far), in MiB."""
        return rss_mib(self.process.pid, field)

    def workers_rss_mb(self) -> float:
        """The RSS of the server's worker processes together."""
        return sum(rss_mib(pid) for pid in descendants(self.process.pid)[1:])

    def cpu_seconds(self) -> float:
        """CPU time (user + system) of the server and its worker processes so far."""
        return cpu_seconds(self.process.pid)

    def stop(self) -> None:
        self.process.terminate()
        self.process.wait(30)


def interpreter_start() -> float:
    """Seconds that ``python -c pass`` takes, start to end."""
    started = time.perf_counter()
    subprocess.run([sys.executable, "-c", "pass"], check=True)
    return time.perf_counter() - started


def copied_in(server: Server, fleet: Path) -> float:
    """Seconds from a log renamed into the fleet (copied into a hidden folder first) to its being listed; then it is removed."""
    name, staging = "car-00/copied-in", fleet / f".incoming-{os.getpid()}"
    shutil.rmtree(staging, ignore_errors=True)
    shutil.copytree(fleet / "car-00" / "seg-000000", staging)
    started = time.perf_counter()
    staging.rename(fleet / name)
    try:
        while not listed(server, name):
            time.sleep(0.05)
        return time.perf_counter() - started
    finally:
        shutil.rmtree(fleet / name)
        while listed(server, name):
            time.sleep(0.05)


def listed(server: Server, name: str) -> bool:
    try:
        server.get(f"/api/logs/{name}")
    except urllib.error.HTTPError as error:
        if error.code == 404:
            return False
        raise
    return True


def timed(server: Server, paths: list[str]) -> list[float]:
    """Milliseconds of each request, one after the other."""
    times = []
    for path in paths:
        started = time.perf_counter()
        server.get(path)
        times.append((time.perf_counter() - started) * 1000)
    return times


def p95(values: list[float]) -> float:
    return statistics.quantiles(values, n=20)[-1]


#: The fleets measured, by name: whether their logs have an index document.
FLEETS = {"indexed": True, "unindexed": False}


def measure(fleet: Path, logs: int, requests: int, scratch: Path, empty_rss: float) -> None:
    """Run the server over ``fleet`` and print what it measures (see the module)."""
    empty, state = scratch / "empty", scratch / f"state-{fleet.name}"
    server = Server(fleet, state)
    listening = server.wait_listening()
    while True:
        page = server.get("/api/logs?limit=1")
        if page["found"] == page["indexed"] == logs:
            break
        time.sleep(0.05)
    build = time.perf_counter() - server.started
    build_cpu = server.cpu_seconds()
    print(
        f"{logs} logs; first build: listening after {listening:.2f} s, every log indexed after {build:.1f} s "
        f"({build_cpu:.1f} s of CPU, the server and its workers)",
        flush=True,
    )

    rng = random.Random(31)
    healthz = timed(server, ["/healthz"] * requests)
    first = timed(server, ["/api/logs"] * requests)
    searches = []
    for _ in range(requests):
        start = FLEET_START + rng.randrange(logs) * 60
        searches.append(f"/api/logs?q=seg-0{rng.randrange(100):02d}&from={start:.0f}&to={start + 3600:.0f}")
    searched = timed(server, searches)
    rss, peak, workers_rss = server.rss_mb(), server.rss_mb("VmHWM"), server.workers_rss_mb()
    copy = copied_in(server, fleet)
    server.stop()

    python = interpreter_start()
    reference = Server(empty, scratch / "empty-state")
    reference_listening = reference.wait_listening()
    reference.stop()
    again = Server(fleet, state)
    relisten = again.wait_listening()
    page = again.get("/api/logs")
    first_page = time.perf_counter() - again.started
    assert page["found"] == logs, page["found"]
    again.stop()

    print(f"reference GET /healthz: p50 {statistics.median(healthz):.1f} ms, p95 {p95(healthz):.1f} ms")
    print(
        f"first page GET /api/logs: p50 {statistics.median(first):.1f} ms, p95 {p95(first):.1f} ms "
        f"(x{p95(first) / p95(healthz):.1f} the reference at p95)"
    )
    print(
        f"search (q + from/to): p50 {statistics.median(searched):.1f} ms, p95 {p95(searched):.1f} ms "
        f"(x{p95(searched) / p95(healthz):.1f} the reference at p95)"
    )
    print(
        f"restart with its catalog: listening after {relisten:.2f} s ({again.cpu:.2f} s of CPU), first page "
        f"({page['indexed']} of {page['found']} indexed) after {first_page:.2f} s; over an empty data directory: listening after "
        f"{reference_listening:.2f} s ({reference.cpu:.2f} s of CPU), x{relisten / reference_listening:.2f}; python -c pass: "
        f"{python:.2f} s, x{relisten / python:.1f}"
    )
    print(f"a log copied in while serving: listed after {copy:.2f} s")
    print(
        f"RSS: {rss:.0f} MB with the catalog (peak {peak:.0f} MB), {empty_rss:.0f} MB over an empty data directory: "
        f"+{rss - empty_rss:.0f} MB (peak +{peak - empty_rss:.0f} MB; worker processes: {workers_rss:.0f} MB)",
        flush=True,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--logs", type=int, default=100_000)
    parser.add_argument("--requests", type=int, default=200)
    parser.add_argument("--quick", action="store_true", help="2 000 logs, 50 requests")
    parser.add_argument("--fleet", choices=sorted(FLEETS), action="append", help="the fleet measured (default: both)")
    parser.add_argument(
        "--fleet-dir",
        type=Path,
        default=Path(tempfile.gettempdir()),
        help="where the fleets are made and kept, as xviz-bench-fleet-N and xviz-bench-fleet-N-unindexed (default: /tmp)",
    )
    args = parser.parse_args()
    if args.quick:
        args.logs, args.requests = 2000, 50
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as scratch:
        empty = Path(scratch) / "empty"
        empty.mkdir()
        reference = Server(empty, Path(scratch) / "empty-state")
        reference.wait_listening()
        reference.wait_ready()
        reference.get("/api/logs")
        empty_rss = reference.rss_mb()
        reference.stop()
        for name in args.fleet or list(FLEETS):
            fleet = args.fleet_dir / f"xviz-bench-fleet-{args.logs}{'' if FLEETS[name] else '-unindexed'}"
            make_fleet(fleet, args.logs, FLEETS[name])
            print(f"-- the {name} fleet ({fleet})", flush=True)
            measure(fleet, args.logs, args.requests, Path(scratch), empty_rss)
    print(f"load average (1 min): {load:.1f} at the start, {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
