"""``xviz-server healthcheck``: ask a running server whether it is healthy.

The check reads the server's effective settings, so it asks the address,
port and scheme (``https`` with ``--certfile``) the server listens on: the
settings it is given itself (flags, ``XVIZ_*`` variables, ``--config``), or,
with ``--pid``, those of a running ``xviz-server serve`` process, whose
command line, environment and working directory are read from ``/proc``.
The server is healthy when ``GET /healthz`` answers 200; anything else (a
refused connection, a timeout, another status) is unhealthy.
"""

from __future__ import annotations

import http.client
import ssl
from pathlib import Path
from urllib.parse import urlsplit

from .exceptions import ConfigError
from .settings import Settings

__all__ = ["ServeProcess", "health_url", "unhealthy_reason"]

#: Addresses that mean "every interface": the check asks loopback instead.
_ANY = {"0.0.0.0": "127.0.0.1", "": "127.0.0.1", "::": "::1"}


def health_url(settings: Settings) -> str:
    """The ``/healthz`` URL of a server running with ``settings``, as seen from its own host."""
    host = _ANY.get(settings.host, settings.host)
    if ":" in host:
        host = f"[{host}]"
    scheme = "https" if settings.certfile else "http"
    return f"{scheme}://{host}:{settings.port}/healthz"


def unhealthy_reason(url: str, timeout: float) -> str | None:
    """``None`` when ``GET url`` answers 200, else what went wrong.

    Over https the certificate is not verified: the check asks its own
    server, by an address the certificate need not name.
    """
    parts = urlsplit(url)
    assert parts.hostname is not None and parts.port is not None
    connection: http.client.HTTPConnection
    if parts.scheme == "https":
        context = ssl.create_default_context()
        context.check_hostname = False
        context.verify_mode = ssl.CERT_NONE
        connection = http.client.HTTPSConnection(parts.hostname, parts.port, timeout=timeout, context=context)
    else:
        connection = http.client.HTTPConnection(parts.hostname, parts.port, timeout=timeout)
    try:
        connection.request("GET", parts.path)
        response = connection.getresponse()
        body = response.read(200).decode("utf-8", "replace").strip()
    except (OSError, http.client.HTTPException) as exc:
        return f"{url}: {exc or type(exc).__name__}"
    finally:
        connection.close()
    if response.status != 200:
        return f"{url}: HTTP {response.status} {body}"
    return None


class ServeProcess:
    """The command line, environment and working directory of a running ``xviz-server serve``."""

    def __init__(self, pid: int) -> None:
        proc = Path("/proc") / str(pid)
        try:
            argv = [part.decode() for part in (proc / "cmdline").read_bytes().split(b"\0")[:-1]]
            environ = (proc / "environ").read_bytes().split(b"\0")[:-1]
            self.cwd = str((proc / "cwd").resolve())
        except OSError as exc:
            raise ConfigError(f"--pid {pid}: cannot read the process: {exc.strerror or exc}") from None
        if "serve" not in argv:
            raise ConfigError(f"--pid {pid}: not an xviz-server serve process: {' '.join(argv)!r}")
        #: The arguments after ``serve``.
        self.arguments = argv[argv.index("serve") + 1 :]
        #: Its environment variables.
        self.environ = dict(item.decode(errors="replace").partition("=")[::2] for item in environ)
