#!/usr/bin/env python3
"""The benchmarks' processes: the server under test, the reference server, client processes, Redis,
and what each costs (CPU seconds of a process and its children, RSS, the cores other processes took).

The reference server and the client processes themselves are :mod:`kit.peers`.
"""

from __future__ import annotations

import json
import os
import re
import socket
import statistics
import subprocess
import sys
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any

from kit import REPO

#: Where ``python -m kit.peers`` runs: the folder that holds the kit.
BENCH = Path(__file__).resolve().parents[1]
PEERS = [sys.executable, "-m", "kit.peers"]
MB = 1e6  # rates in MB/s are 10^6 bytes per second
MIB = 1 << 20  # memory in MiB, like --cache-mb
QUIET = 0.25  # a trial is "quiet" when other processes used fewer cores than this

# ================================================================ processes


def _clean_env() -> dict[str, str]:
    """The environment without XVIZ_* settings (flags here say everything) and proxies."""
    return {k: v for k, v in os.environ.items() if not k.startswith("XVIZ_") and "proxy" not in k.lower()}


class Process:
    """A child process that prints ``ready`` (a regex with the port) on stderr; stderr is drained after."""

    def __init__(self, args: list[str], ready: str, name: str, cwd: Path = REPO) -> None:
        self.name = name
        self.started = time.perf_counter()
        self.popen = subprocess.Popen(
            args,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
            cwd=cwd,
            env=_clean_env(),
        )
        self.tail: deque[str] = deque(maxlen=30)
        assert self.popen.stderr is not None
        for text in self.popen.stderr:
            self.tail.append(text)
            match = re.search(ready, text)
            if match:
                self.port = int(match.group(1))
                break
        else:
            raise RuntimeError(f"{name} exited before listening:\n{''.join(self.tail)}")
        self.startup_s = time.perf_counter() - self.started
        # Keep draining: a server logging one line per session would block on a full pipe.
        self._drain = threading.Thread(target=self._read_rest, daemon=True)
        self._drain.start()

    def _read_rest(self) -> None:
        assert self.popen.stderr is not None
        for text in self.popen.stderr:
            self.tail.append(text)

    @property
    def pid(self) -> int:
        return self.popen.pid

    def url(self, path: str = "") -> str:
        return f"ws://127.0.0.1:{self.port}/{path}"

    def stop(self) -> None:
        if self.popen.poll() is None:
            self.popen.terminate()
            try:
                self.popen.wait(15)
            except subprocess.TimeoutExpired:
                self.popen.kill()
                self.popen.wait()

    def __enter__(self) -> Process:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def start_server(root: Path | str | None, *extra: str) -> Process:
    """``xviz-server serve`` on a free loopback port, serving ``root`` (a folder or an ``s3://`` URL) if given."""
    data_dir = [] if root is None else ["--data-dir", str(root)]
    args = [sys.executable, "-m", "xviz_server", "serve", *data_dir, "--host", "127.0.0.1", "--port", "0", *extra]
    return Process(args, r"listening on ws://127\.0\.0\.1:(\d+)/", "xviz-server")


def start_reference(logs: dict[str, Path]) -> Process:
    spec = json.dumps({name: str(path) for name, path in logs.items()})
    return Process(
        [*PEERS, "--role", "reference", spec],
        r"reference listening on ws://127\.0\.0\.1:(\d+)/",
        "reference",
        cwd=BENCH,
    )


def start_foxglove_sdk(log: Path) -> Process:
    """The published foxglove-sdk server playing ``log``'s Foxglove messages (see :func:`kit.peers.foxglove_sdk_main`)."""
    return Process(
        [*PEERS, "--role", "foxglove-sdk", str(log)],
        r"foxglove-sdk listening on ws://127\.0\.0\.1:(\d+)/",
        "foxglove-sdk",
        cwd=BENCH,
    )


def descendants(pid: int) -> list[int]:
    """``pid`` and every process below it (the server's worker processes, if any)."""
    found, todo = [], [pid]
    while todo:
        current = todo.pop()
        found.append(current)
        try:
            for task in os.listdir(f"/proc/{current}/task"):
                with open(f"/proc/{current}/task/{task}/children") as children:
                    todo.extend(int(c) for c in children.read().split())
        except OSError:
            pass
    return found


def rss_mib(pid: int, field: str = "VmRSS") -> float:
    """The RSS of ``pid`` in MiB (``field`` ``VmHWM``: its peak so far); 0 for a process gone."""
    try:
        with open(f"/proc/{pid}/status") as status:
            for line in status:
                if line.startswith(f"{field}:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


def _own_cpu(pid: int) -> float:
    """User + system CPU time of one process (all its threads)."""
    try:
        with open(f"/proc/{pid}/stat") as stat:
            fields = stat.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return 0.0


def cpu_seconds(pid: int) -> float:
    """CPU time of ``pid`` and its live descendants (the server's worker processes, if any)."""
    return sum(_own_cpu(each) for each in descendants(pid))


def other_cpu() -> float:
    """CPU seconds used so far on the machine by processes outside this benchmark's tree.

    The machine may be shared: the difference of two readings says how much
    of it others took meanwhile. Busy time (from /proc/stat, interrupts
    included) minus this process, its reaped children and its live
    descendants; short-lived processes are counted too. Approximate: tick
    sampled, and interrupt work done for our sockets counts as "others".
    """
    with open("/proc/stat") as stat:
        fields = [int(x) for x in stat.readline().split()[1:]]
    busy = sum(fields[i] for i in (0, 1, 2, 5, 6)) / os.sysconf("SC_CLK_TCK")  # user nice system irq softirq
    times = os.times()
    ours = times.user + times.system + times.children_user + times.children_system
    ours += sum(_own_cpu(pid) for pid in descendants(os.getpid())[1:])
    return busy - ours


def other_cores(cpu_before: float, wall_before: float) -> float:
    """Cores used by other processes since :func:`other_cpu` read ``cpu_before`` at ``wall_before``.

    Readings are tick sampled, so an idle machine can come out a little
    below zero; that is reported as 0.
    """
    return max(0.0, (other_cpu() - cpu_before) / (time.perf_counter() - wall_before))


class RssSampler:
    """Samples the RSS of a process (and, separately, its descendants) every few ms in a thread."""

    def __init__(self, pid: int, interval: float = 0.01) -> None:
        self.pid, self.interval = pid, interval
        self.peak = self.peak_total = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            main = rss_mib(self.pid)
            total = main + sum(rss_mib(p) for p in descendants(self.pid)[1:])
            self.peak, self.peak_total = max(self.peak, main), max(self.peak_total, total)
            self._stop.wait(self.interval)

    def __enter__(self) -> RssSampler:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


def run_clients(spec: dict[str, Any], procs: int = 1, server_pid: int | None = None) -> dict[str, Any]:
    """Run ``spec`` in ``procs`` client processes started together; aggregate what they measured.

    Each process connects its clients, says ``ready``, and starts on ``go``, so
    that process start-up and connection set-up are outside the measured time.
    """
    counts = [spec.get("clients", 1) // procs + (i < spec.get("clients", 1) % procs) for i in range(procs)]
    stalled = [spec.get("stalled", 0) // procs + (i < spec.get("stalled", 0) % procs) for i in range(procs)]
    children = []
    for clients, stalls in zip(counts, stalled):
        part = {**spec, "clients": clients, "stalled": stalls}
        child = subprocess.Popen(
            [*PEERS, "--role", "client", "-"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            cwd=BENCH,
            env=_clean_env(),
        )
        assert child.stdin is not None
        child.stdin.write(json.dumps(part) + "\n")  # the spec, on stdin: a schedule can be long
        child.stdin.flush()
        children.append(child)
    try:
        for child in children:
            assert child.stdout is not None
            text = child.stdout.readline()
            if text.strip() != "ready":
                raise RuntimeError(f"client process failed before starting: {text!r} (spec {spec})")
        cpu_before = cpu_seconds(server_pid) if server_pid else 0.0
        other_before, wall_before = other_cpu(), time.perf_counter()
        for child in children:
            assert child.stdin is not None
            child.stdin.write("go\n")
            child.stdin.flush()
        parts = []
        for child in children:
            assert child.stdout is not None
            text = child.stdout.readline()
            if child.wait() or not text:
                raise RuntimeError(f"client process exited with {child.returncode} (spec {spec})")
            parts.append(json.loads(text))
    finally:
        for child in children:
            if child.poll() is None:
                child.kill()
                child.wait()
    server_cpu = cpu_seconds(server_pid) - cpu_before if server_pid else None
    other = other_cores(other_before, wall_before)
    if spec["task"] != "stream":
        return {**parts[0], "other_cpu": other}
    if len(parts) == 1:
        result = parts[0]
    else:
        result = {
            key: sum(p[key] for p in parts) for key in ("bytes", "wire_bytes", "frames", "errors", "client_cpu_s")
        }
        result["started"] = min(p["started"] for p in parts)
        result["ended"] = max(p["ended"] for p in parts)
        result["seconds"] = result["ended"] - result["started"]
        result["first_frame_ms"] = statistics.median(x for p in parts for x in p["first_frame_list"])
        result["frames_per_request"] = sorted({x for p in parts for x in p["frames_per_request"]})
        result["extensions"] = parts[0]["extensions"]
    seconds = result["seconds"]
    result["client_procs"] = procs
    result["other_cpu"] = other  # cores used by other processes on the machine meanwhile
    result["mb_s"] = result["bytes"] / MB / seconds
    result["wire_mb_s"] = result["wire_bytes"] / MB / seconds
    result["frames_s"] = result["frames"] / seconds
    result["client_cpu"] = result["client_cpu_s"] / seconds  # in cores
    if server_cpu is not None:
        result["server_cpu_s"] = server_cpu
        result["server_cpu"] = server_cpu / seconds
    result.pop("first_frame_list", None)
    return result


# ================================================================ Redis


def free_port() -> int:
    """A loopback TCP port free at the time of the call."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def start_redis(directory: str) -> tuple[subprocess.Popen[bytes], str]:
    """Debian's redis-server on a free loopback port, without persistence, in ``directory``; and its URL."""
    port = free_port()
    process = subprocess.Popen(
        [
            "redis-server",
            "--port",
            str(port),
            "--bind",
            "127.0.0.1",
            "--save",
            "",
            "--appendonly",
            "no",
            "--dir",
            directory,
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    for _ in range(100):
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.1).close()
            break
        except OSError:
            time.sleep(0.05)
    return process, f"redis://127.0.0.1:{port}/0"


def address(broker: str) -> tuple[str, int]:
    """The ``(host, port)`` of a ``redis://HOST:PORT/0`` URL."""
    host, port = broker.removeprefix("redis://").split("/")[0].split(":")
    return host, int(port)


def resp(*parts: bytes, more: int = 0) -> bytes:
    """A Redis command in RESP, or its start when ``more`` parts follow."""
    return b"*%d\r\n" % (len(parts) + more) + b"".join(b"$%d\r\n%s\r\n" % (len(part), part) for part in parts)
