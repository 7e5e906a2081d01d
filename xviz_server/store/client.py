"""Clients of an S3-compatible object store (AWS S3, MinIO, ...), made with obstore, and what their failures mean.

The store is configured the way every AWS tool is: ``AWS_ACCESS_KEY_ID``,
``AWS_SECRET_ACCESS_KEY``, ``AWS_SESSION_TOKEN``, ``AWS_REGION`` (or
``AWS_DEFAULT_REGION``) and ``AWS_ENDPOINT_URL`` (or ``AWS_ENDPOINT_URL_S3``)
for S3-compatible stores; what the environment leaves out is taken from the
profile ``AWS_PROFILE`` (``default``) of the shared files
``~/.aws/credentials`` and ``~/.aws/config`` (or ``AWS_SHARED_CREDENTIALS_FILE``
and ``AWS_CONFIG_FILE``). Plain ``http://`` is allowed when the endpoint URL
says ``http://`` or ``AWS_ALLOW_HTTP`` is ``true``.

Time limits, so that a dead store never holds a session: connecting gives up
after :data:`CONNECT_TIMEOUT`; a request, from connecting to the end of its
body, after ``timeout`` seconds (``--store-timeout``). A GET that fails with
a 5xx, a timeout or a lost connection is tried again ``retries`` times
(``--store-retries``), after an exponential backoff with jitter from
:data:`BACKOFF_START` to :data:`BACKOFF_MAX` (obstore retries, a body cut
short included). A missing object, a 401 or a 403 is not retried. However
the store behaves, a request with its retries ends within
``(retries + 1) * (timeout + CONNECT_TIMEOUT) + retries * BACKOFF_MAX + 1``
seconds. What still fails is a
:class:`~xviz_server.exceptions.StoreError` naming the object's URL and the
cause, never a credential.

Bytes are read by range, as a stream that is left once the range is in
(:func:`get_range`): a store whose answer says it is longer than asked, or
sends without end, costs no more memory than the range.
"""

from __future__ import annotations

import configparser
import os
import re
import time
from dataclasses import dataclass, field
from datetime import timedelta
from pathlib import Path
from typing import TYPE_CHECKING

import obstore
from obstore.exceptions import NotFoundError, PermissionDeniedError, UnauthenticatedError
from obstore.store import S3Store

from ..exceptions import ConfigError, StoreError

if TYPE_CHECKING:
    from obstore.store import ClientConfig, RetryConfig, S3Config

__all__ = [
    "SCHEME",
    "CONNECT_TIMEOUT",
    "BACKOFF_START",
    "BACKOFF_MAX",
    "StoreConfig",
    "store_config",
    "s3_client",
    "failure",
    "store_error",
    "get_range",
    "get_range_async",
]

SCHEME = "s3://"
#: Seconds to open a connection to the store.
CONNECT_TIMEOUT = 5.0
#: Seconds before the first retry of a failed GET; each next waits up to twice as long.
BACKOFF_START = 0.1
#: Most seconds between two tries of a GET.
BACKOFF_MAX = 2.0
_STATUS = re.compile(r"status code: (\d{3})")
_STREAM_CHUNK = 1 << 20  # bytes taken from an answer's body at a time


@dataclass(frozen=True)
class StoreConfig:
    """How to reach a bucket, as :func:`store_config` resolved it: what a worker process makes its own client from.

    ``timeout`` and ``retries`` bound each request. ``settings`` are what
    obstore is given (endpoint, region, credentials): ``repr`` never shows
    them, and neither does any message.
    """

    bucket: str
    timeout: float
    retries: int
    settings: tuple[tuple[str, str], ...] = field(repr=False)
    allow_http: bool = False


def store_config(bucket: str, timeout: float, retries: int) -> StoreConfig:
    """The configuration of ``bucket`` from the environment and the AWS files."""
    config, client = _aws_settings()
    settings = tuple(sorted((key, str(value)) for key, value in config.items()))
    return StoreConfig(bucket, timeout, retries, settings, bool(client.get("allow_http")))


def s3_client(store: StoreConfig) -> S3Store:
    """An obstore client of ``store`` with the time limits and retries of the module's docstring."""
    client: ClientConfig = {
        "allow_http": store.allow_http,
        "connect_timeout": timedelta(seconds=CONNECT_TIMEOUT),
        "timeout": timedelta(seconds=store.timeout),
    }
    retry: RetryConfig = {
        "max_retries": store.retries,
        "retry_timeout": timedelta(seconds=(store.retries + 1) * store.timeout),
        "backoff": {
            "init_backoff": timedelta(seconds=BACKOFF_START),
            "max_backoff": timedelta(seconds=BACKOFF_MAX),
            "base": 2,
        },
    }
    config: S3Config = dict(store.settings)  # type: ignore[assignment]  # the keys _aws_settings gives
    return S3Store(store.bucket, config=config, client_options=client, retry_config=retry)


def get_range(store: S3Store, key: str, start: int, end: int) -> bytes:
    """Bytes ``[start, end)`` of object ``key``: no more than that is read, whatever the store sends."""
    parts: list[bytes] = []
    wanted = end - start
    for chunk in obstore.get(store, key, options={"range": (start, end)}).stream(_STREAM_CHUNK):
        parts.append(bytes(chunk))
        wanted -= len(parts[-1])
        if wanted <= 0:
            break
    return b"".join(parts)[: end - start]


async def get_range_async(store: S3Store, key: str, start: int, end: int) -> bytes:
    """:func:`get_range` for the event loop."""
    parts: list[bytes] = []
    wanted = end - start
    async for chunk in (await obstore.get_async(store, key, options={"range": (start, end)})).stream(_STREAM_CHUNK):
        parts.append(bytes(chunk))
        wanted -= len(parts[-1])
        if wanted <= 0:
            break
    return b"".join(parts)[: end - start]


def failure(url: str, exc: Exception, started: float, timeout: float) -> StoreError:
    """An obstore request for ``url``, begun at ``started`` (``time.monotonic``), failed with ``exc``: the error to raise.

    ``exc`` is one of obstore's errors, or a builtin one (obstore raises
    :class:`FileNotFoundError` for some); a request that took ``timeout``
    seconds or more is said to have timed out.
    """
    return _explain(url, exc, timeout if time.monotonic() - started >= timeout else None)


def _aws_settings() -> tuple[S3Config, ClientConfig]:
    """What the environment leaves out, from the shared AWS files; plain HTTP where the endpoint says so.

    obstore reads the ``AWS_*`` variables itself; the values returned here
    come from the files (for keys the environment does not set) and are
    given to obstore as its configuration.
    """
    profile = os.environ.get("AWS_PROFILE") or "default"
    credentials = _profile(os.environ.get("AWS_SHARED_CREDENTIALS_FILE", "~/.aws/credentials"), profile)
    settings = _profile(
        os.environ.get("AWS_CONFIG_FILE", "~/.aws/config"), profile if profile == "default" else f"profile {profile}"
    )
    from_files = {**settings, **credentials}
    config: dict[str, str] = {}
    for key, variables, option in (
        ("access_key_id", ["AWS_ACCESS_KEY_ID"], "aws_access_key_id"),
        ("secret_access_key", ["AWS_SECRET_ACCESS_KEY"], "aws_secret_access_key"),
        ("session_token", ["AWS_SESSION_TOKEN"], "aws_session_token"),
        ("region", ["AWS_REGION", "AWS_DEFAULT_REGION"], "region"),
        ("endpoint", ["AWS_ENDPOINT_URL_S3", "AWS_ENDPOINT_URL"], "endpoint_url"),
    ):
        given = next((os.environ[v] for v in variables if os.environ.get(v)), None)
        value = given or from_files.get(option)
        if value:
            config[key] = value
    endpoint = config.get("endpoint", "")
    allow = os.environ.get("AWS_ALLOW_HTTP", "").lower() in ("1", "true") or endpoint.startswith("http://")
    client: ClientConfig = {"allow_http": allow}
    return config, client  # type: ignore[return-value]  # S3Config is a TypedDict of these keys


def _profile(path: str, section: str) -> dict[str, str]:
    """The options of one section of an AWS shared file, or nothing if the file or section is not there."""
    parser = configparser.ConfigParser(interpolation=None)
    try:
        parser.read(Path(path).expanduser(), encoding="utf-8")
    except (configparser.Error, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not an AWS configuration file: {type(exc).__name__}") from None
    return dict(parser[section]) if parser.has_section(section) else {}


def _explain(url: str, exc: Exception, timeout: float | None) -> StoreError:
    """An obstore failure as a :class:`StoreError`: the cause, without the request's headers or the endpoint.

    ``timeout`` is the time limit of a try when the failure took that long.
    """
    text = str(exc)
    status = _STATUS.search(text)
    if isinstance(exc, (FileNotFoundError, NotFoundError)) or (status and status.group(1) == "404"):
        return store_error(url, "no such object (404)")
    if isinstance(exc, (PermissionError, PermissionDeniedError, UnauthenticatedError)) or (
        status and status.group(1) in ("401", "403")
    ):
        return store_error(
            url, f"access denied ({status.group(1) if status else 403}): check the credentials and the bucket policy"
        )
    retried = re.search(r"after (\d+) retries", text)
    after = f" after {retried.group(1)} {'retry' if retried.group(1) == '1' else 'retries'}" if retried else ""
    if status:
        return store_error(url, f"the store answered {status.group(1)}{after}")
    if timeout is not None:
        return store_error(url, f"timed out (no whole answer within {timeout:g} s){after}")
    return store_error(url, f"the connection failed or was cut short{after}")


def store_error(url: str, cause: str) -> StoreError:
    """The error for the object at ``url``, saying ``cause``; it names the object, never a credential."""
    return StoreError(f"{url}: {cause}", key=url)
