"""A real slow network link on this machine: a veth pair into a network namespace, shaped with ``tc tbf`` (root only).

The server listens on the host side (:attr:`TcLink.host`); a client
connects from inside the namespace (:meth:`TcLink.connect` for a socket
made here, or ``ip netns exec`` :attr:`TcLink.namespace` for a process).
The way out of the host, towards the client, carries at most
:meth:`TcLink.shape`'s rate, with bursts of 10 ms of it and a queue of
``latency`` seconds (``tc tbf``; this kernel may have no ``netem``); the way
back is unshaped.

The host side sends packets of at most :data:`PACKET` bytes (its
``gso_max_size``), below every burst :meth:`TcLink.shape` sets. Otherwise
TCP hands the qdisc segmentation-offload packets of up to 64 KiB: ``tbf``
never sends a packet larger than its bucket, so one queued under a fast
rate's large bucket blocks the queue for good once the rate is lowered
(the link carries nothing more, and every connection over it stalls).
"""

from __future__ import annotations

import contextlib
import ctypes
import itertools
import os
import shutil
import socket
import subprocess
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

__all__ = ["PACKET", "TcLink", "can_shape_links", "tc_link"]

#: Largest packet the shaped side hands its qdisc (bytes of payload per offload packet): below any bucket.
PACKET = 16_384
#: Smallest bucket (burst) of a shaped link, bytes.
_LEAST_BURST = 32_000
_LINKS = itertools.count()
_CLONE_NEWNET = 0x40000000


def can_shape_links() -> bool:
    """Whether this process may make network namespaces and shape links with ``tc`` (root, with ``ip`` and ``tc``)."""
    return os.geteuid() == 0 and shutil.which("ip") is not None and shutil.which("tc") is not None


def _run(command: str) -> None:
    subprocess.run(command.split(), check=True, capture_output=True)


@dataclass
class TcLink:
    """A veth pair from this network namespace (:attr:`host`) into one of its own, the way out shaped with tc tbf."""

    namespace: str
    device: str
    host: str
    peer: str
    latency: float = 0.1
    shaped: bool = False
    bucket: int | None = None

    def shape(self, mbps: float) -> None:
        """Carry at most ``mbps`` Mbit/s towards the namespace (bursts of :attr:`bucket` bytes, by default 10 ms
        of the rate; ``latency`` s of queue).

        A change keeps the packets queued (a new qdisc would drop them, and TCP would stall on its timeouts).
        """
        burst = self.bucket or max(_LEAST_BURST, int(mbps * 125_000 / 100))
        verb = "change" if self.shaped else "add"
        _run(
            f"tc qdisc {verb} dev {self.device} root tbf rate {mbps}mbit burst {burst} latency {self.latency * 1000:g}ms"
        )
        self.shaped = True

    def connect(self, port: int) -> socket.socket:
        """A TCP socket from inside the namespace, connected to ``port`` of :attr:`host`."""
        result: dict[str, Any] = {}

        def run() -> None:  # setns() moves the calling thread only: a thread of its own, which then ends
            fd = os.open(f"/var/run/netns/{self.namespace}", os.O_RDONLY)
            try:
                if ctypes.CDLL(None, use_errno=True).setns(fd, _CLONE_NEWNET) != 0:
                    raise OSError(ctypes.get_errno(), "setns")
                result["socket"] = socket.create_connection((self.host, port), timeout=10)
            except BaseException as exc:
                result["error"] = exc
            finally:
                os.close(fd)

        thread = threading.Thread(target=run)
        thread.start()
        thread.join()
        if "error" in result:
            raise result["error"]
        sock: socket.socket = result["socket"]
        sock.settimeout(None)
        return sock


@contextlib.contextmanager
def tc_link(mbps: float, latency: float = 0.1, bucket: int | None = None, prefix: str = "xvl") -> Iterator[TcLink]:
    """A :class:`TcLink` shaped to ``mbps`` (a ``bucket`` of that many bytes, else 10 ms of the rate; a queue of
    ``latency`` seconds), removed on exit; names unique to this process (``<prefix><pid><letter>``, at most
    15 characters with ``prefix`` of at most 5)."""
    number = next(_LINKS)
    name = f"{prefix}{os.getpid()}{chr(97 + number % 26)}"
    subnet = f"10.{200 + number % 50}.{os.getpid() % 250}"
    link = TcLink(name, f"{name}h", f"{subnet}.1", f"{subnet}.2", latency, bucket=bucket)
    try:
        for command in (
            f"ip netns add {name}",
            f"ip link add {name}h type veth peer name {name}v",
            f"ip link set {name}h gso_max_size {PACKET}",
            f"ip link set {name}v netns {name}",
            f"ip addr add {link.host}/24 dev {name}h",
            f"ip link set {name}h up",
            f"ip netns exec {name} ip addr add {link.peer}/24 dev {name}v",
            f"ip netns exec {name} ip link set {name}v up",
            f"ip netns exec {name} ip link set lo up",
        ):
            _run(command)
        link.shape(mbps)
        yield link
    finally:
        subprocess.run(["ip", "link", "del", f"{name}h"], capture_output=True)
        subprocess.run(["ip", "netns", "del", name], capture_output=True)
