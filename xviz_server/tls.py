"""TLS for ``--certfile``/``--keyfile``: the server's context, checked so that every mistake names its file."""

from __future__ import annotations

import logging
import os
import ssl
import stat
from pathlib import Path

from .exceptions import ConfigError

__all__ = ["server_context"]

logger = logging.getLogger(__name__)


def server_context(certfile: Path, keyfile: Path | None) -> ssl.SSLContext:
    """The server's TLS context for a PEM certificate (chain) and its key.

    Raises :class:`~xviz_server.exceptions.ConfigError` naming the file that
    is missing, unreadable, not PEM, encrypted (the server cannot ask for a
    passphrase) or not the certificate's key. Logs a warning when the key can
    be read by every user of the machine.
    """
    key = keyfile or certfile
    _check_pem(certfile, "--certfile", b"-----BEGIN CERTIFICATE-----", "certificate")
    _check_pem(key, "--keyfile" if keyfile else "--certfile", b"PRIVATE KEY-----", "private key")

    def no_passphrase() -> bytes:
        raise ConfigError(
            f"--keyfile {key}: the key is encrypted; give it unencrypted (e.g. openssl pkey -in KEY -out KEY.plain)"
        )

    context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    try:
        context.load_cert_chain(certfile, keyfile, password=no_passphrase)
    except ssl.SSLError as exc:
        problem = "the key is not the certificate's key" if exc.reason == "KEY_VALUES_MISMATCH" else str(exc)
        raise ConfigError(f"--certfile {certfile}, --keyfile {key}: {problem}") from None
    if os.stat(key).st_mode & stat.S_IROTH:
        logger.warning("the TLS key %s can be read by every user of this machine: chmod o-r it", key)
    return context


def _check_pem(path: Path, option: str, marker: bytes, what: str) -> None:
    """Raise :class:`ConfigError` unless ``path`` can be read and holds a PEM ``what``."""
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise ConfigError(f"{option} {path}: {exc.strerror or exc}") from None
    if marker not in data:
        raise ConfigError(f"{option} {path}: no PEM {what} in it")
