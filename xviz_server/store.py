"""Logs in an S3-compatible object store (AWS S3, MinIO, ...), read with obstore.

A data root ``s3://BUCKET/PREFIX`` serves every static log under the
prefix, named by its key path below it (``s3://b/fleet/kitti/0005/1-frame.glb``
is the log ``kitti/0005`` of the root ``s3://b/fleet``), in the layout of
:mod:`xviz_server.layout`. A log is a :class:`StoreFolder`: the static-log
provider reads it as it reads a directory, one GET per file.

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
"""

from __future__ import annotations

import asyncio
import configparser
import logging
import os
import re
import time
from dataclasses import dataclass
from datetime import timedelta
from pathlib import Path
from typing import TYPE_CHECKING, Any

import obstore
from obstore.exceptions import BaseError, NotFoundError, PermissionDeniedError, UnauthenticatedError
from obstore.store import S3Store

from .exceptions import ConfigError, StoreError
from .layout import FRAME_FILE, LOG
from .readahead import ReadAhead
from .settings import Settings

if TYPE_CHECKING:
    from obstore import ObjectMeta
    from obstore.store import ClientConfig, RetryConfig, S3Config

__all__ = [
    "SCHEME",
    "CONNECT_TIMEOUT",
    "BACKOFF_START",
    "BACKOFF_MAX",
    "is_store_url",
    "data_roots",
    "ObjectStore",
    "StoreFolder",
    "StoredLog",
]

logger = logging.getLogger(__name__)

SCHEME = "s3://"
#: Seconds to open a connection to the store.
CONNECT_TIMEOUT = 5.0
#: Seconds before the first retry of a failed GET; each next waits up to twice as long.
BACKOFF_START = 0.1
#: Most seconds between two tries of a GET.
BACKOFF_MAX = 2.0
#: S3 bucket names: 3 to 63 lower-case letters, digits, dots and hyphens.
_BUCKET = re.compile(r"[a-z0-9][a-z0-9.-]{1,61}[a-z0-9]")
_STATUS = re.compile(r"status code: (\d{3})")


def is_store_url(text: str) -> bool:
    """Whether a ``--data-dir`` value names an object store rather than a directory."""
    return text.startswith(SCHEME)


def data_roots(settings: Settings) -> list[Path | ObjectStore]:
    """The ``--data-dir`` values: directories, and object stores configured by the settings and the AWS files."""
    read_ahead = ReadAhead(settings.store_read_ahead, int(settings.store_read_ahead_mb * (1 << 20)))
    return [
        ObjectStore(root, timeout=settings.store_timeout, retries=settings.store_retries, read_ahead=read_ahead)
        if is_store_url(root)
        else Path(root)
        for root in settings.data_dir
    ]


@dataclass(frozen=True)
class StoredLog:
    """A log found in a store: its name and its folder (the counterpart of :class:`~xviz_server.layout.Found`)."""

    name: str
    folder: StoreFolder
    kind: str = LOG


class ObjectStore:
    """One ``s3://BUCKET/PREFIX`` data root.

    ``timeout`` and ``retries`` bound each GET (see the module's
    docstring); ``read_ahead`` is how far a stream reads ahead of a log
    here. Raises :class:`~xviz_server.exceptions.ConfigError` for a URL
    that is not ``s3://BUCKET[/PREFIX]``.
    """

    def __init__(self, url: str, *, timeout: float, retries: int, read_ahead: ReadAhead) -> None:
        self.bucket, self.prefix = _parse(url)
        self.url = f"{SCHEME}{self.bucket}/{self.prefix}".rstrip("/")
        self.read_ahead = read_ahead
        self._timeout = timeout
        self._retries = retries
        # Beyond obstore's own limits: every try, every backoff, and some slack.
        self._deadline = (retries + 1) * (timeout + CONNECT_TIMEOUT) + retries * BACKOFF_MAX + 1
        config, client = _aws_settings()
        client["connect_timeout"] = timedelta(seconds=CONNECT_TIMEOUT)
        client["timeout"] = timedelta(seconds=timeout)
        retry: RetryConfig = {
            "max_retries": retries,
            "retry_timeout": timedelta(seconds=(retries + 1) * timeout),
            "backoff": {"init_backoff": timedelta(seconds=BACKOFF_START), "max_backoff": timedelta(seconds=BACKOFF_MAX), "base": 2},
        }
        self._store = S3Store(self.bucket, config=config, client_options=client, retry_config=retry)

    def key_url(self, key: str) -> str:
        """The ``s3://`` URL of an object (what errors name)."""
        return f"{SCHEME}{self.bucket}/{key}"

    def _key(self, name: str) -> str:
        """The key of ``name`` below the prefix."""
        return f"{self.prefix}/{name}" if self.prefix else name

    async def discover(self) -> list[StoredLog]:
        """Every log under the prefix, in name order: one listing of the whole prefix.

        A folder holding message files is a log; folders below a log are
        searched too, and hidden ones (a component starting with ``.``) are
        not. The prefix itself is a log named after its last component when
        it holds message files.
        """
        base = self._key("")
        try:
            objects = await self._guard(obstore.list(self._store, base or None, chunk_size=1000).collect_async(), base)
        except StoreError as exc:
            logger.warning("cannot list %s: %s", self.url, exc)
            return []
        folders: set[str] = set()
        for meta in objects:
            relative = meta["path"][len(base):]
            folder, _, file = relative.rpartition("/")
            if FRAME_FILE.fullmatch(file) and not any(part.startswith(".") for part in relative.split("/")):
                folders.add(folder)
        return [self._log(folder) for folder in sorted(folders)]

    async def lookup(self, name: str) -> StoredLog | None:
        """The log ``name`` if its folder holds message files: one listing of that folder."""
        folder = StoreFolder(self, self._key(name))
        try:
            files = await folder.files()
        except StoreError as exc:
            logger.warning("cannot look for %r in %s: %s", name, self.url, exc)
            return None
        return self._log(name, folder) if files else None

    def _log(self, name: str, folder: StoreFolder | None = None) -> StoredLog:
        own = name or self.prefix.rpartition("/")[2] or self.bucket
        return StoredLog(own, folder or StoreFolder(self, self._key(name)))

    async def list_folder(self, prefix: str) -> list[ObjectMeta]:
        """The objects directly in the folder ``prefix`` (not in folders below it)."""
        listing = self._store.list_with_delimiter_async(prefix.rstrip("/") + "/")
        result = await self._guard(listing, prefix)
        return list(result["objects"])

    async def get(self, key: str) -> bytes:
        """The whole object ``key``; raises :class:`~xviz_server.exceptions.StoreError` after the retries."""
        return await self._guard(self._fetch(key), key)

    async def _fetch(self, key: str) -> bytes:
        response = await obstore.get_async(self._store, key)
        return bytes(await response.bytes_async())

    async def _guard(self, request: Any, key: str) -> Any:
        """Await an obstore request within the deadline; its failure as a :class:`StoreError`."""
        started = time.monotonic()
        try:
            return await asyncio.wait_for(request, self._deadline)
        except asyncio.TimeoutError:
            raise _failure(self.key_url(key), f"no answer in {self._deadline:g} s") from None
        except (BaseError, OSError) as exc:  # obstore's own classes, and builtins (FileNotFoundError) for some
            timed_out = time.monotonic() - started >= self._timeout
            raise _explain(self.key_url(key), exc, self._timeout if timed_out else None) from None


class StoreFolder:
    """A log's folder in a store: the objects directly below one key prefix."""

    def __init__(self, store: ObjectStore, prefix: str) -> None:
        self.store = store
        self.prefix = prefix.rstrip("/")
        self.location = store.key_url(self.prefix)
        self.read_ahead: ReadAhead | None = store.read_ahead
        self._sizes: dict[str, int] = {}

    async def files(self) -> dict[int, str]:
        files = {}
        for meta in await self.store.list_folder(self.prefix):
            name = meta["path"].rpartition("/")[2]
            if match := FRAME_FILE.fullmatch(name):
                files[int(match.group(1))] = name
                self._sizes[name] = meta["size"]
        return files

    async def read(self, name: str) -> bytes:
        return await self.store.get(f"{self.prefix}/{name}")

    def size(self, name: str) -> int | None:
        return self._sizes.get(name)


def _parse(url: str) -> tuple[str, str]:
    """Bucket and prefix (without slashes at its ends) of ``s3://BUCKET[/PREFIX]``."""
    rest = url[len(SCHEME):] if is_store_url(url) else ""
    bucket, _, prefix = rest.partition("/")
    if not _BUCKET.fullmatch(bucket):
        shown = bucket if "@" not in bucket and ":" not in bucket else "(hidden: it may hold a credential)"
        raise ConfigError(
            f"--data-dir {SCHEME}{shown}...: not an S3 bucket name (3 to 63 lower-case letters, digits, '.' and '-'); "
            "credentials go in the AWS variables or files, not in the URL"
        )
    return bucket, prefix.strip("/")


def _aws_settings() -> tuple[S3Config, ClientConfig]:
    """What the environment leaves out, from the shared AWS files; plain HTTP where the endpoint says so.

    obstore reads the ``AWS_*`` variables itself; the values returned here
    come from the files (for keys the environment does not set) and are
    given to obstore as its configuration.
    """
    profile = os.environ.get("AWS_PROFILE") or "default"
    credentials = _profile(os.environ.get("AWS_SHARED_CREDENTIALS_FILE", "~/.aws/credentials"), profile)
    settings = _profile(os.environ.get("AWS_CONFIG_FILE", "~/.aws/config"), profile if profile == "default" else f"profile {profile}")
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
        return _failure(url, "no such object (404)")
    if isinstance(exc, (PermissionError, PermissionDeniedError, UnauthenticatedError)) or (status and status.group(1) in ("401", "403")):
        return _failure(url, f"access denied ({status.group(1) if status else 403}): check the credentials and the bucket policy")
    retried = re.search(r"after (\d+) retries", text)
    after = f" after {retried.group(1)} {'retry' if retried.group(1) == '1' else 'retries'}" if retried else ""
    if status:
        return _failure(url, f"the store answered {status.group(1)}{after}")
    if timeout is not None:
        return _failure(url, f"timed out (no whole answer within {timeout:g} s){after}")
    return _failure(url, f"the connection failed or was cut short{after}")


def _failure(url: str, cause: str) -> StoreError:
    return StoreError(f"{url}: {cause}", key=url)
