"""Server settings: flags over ``XVIZ_*`` environment variables over a TOML file over defaults.

The configuration file is TOML with the settings' names as keys
(``cache_mb = 256``); it is named by ``--config`` or ``XVIZ_CONFIG``.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Annotated, Any, Literal
from urllib.parse import urlsplit

import orjson
from pydantic import Field, ValidationInfo, field_validator, model_validator
from pydantic_settings import (
    BaseSettings,
    NoDecode,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
    TomlConfigSettingsSource,
)

from .datasets import DEFAULT_IMAGE_WIDTH
from .exceptions import ConfigError
from .logfmt import redact_password

__all__ = ["SECRETS", "Settings", "load_settings"]

#: What --frame-ancestors takes: 'self', or an origin (a host may start with ``*.``).
_FRAME_ANCESTOR = re.compile(r"'self'|https?://(\*\.)?[A-Za-z0-9-]+(\.[A-Za-z0-9-]+)*(:\d{1,5})?")

#: The settings that are secrets: never printed or logged.
SECRETS = ("ingest_token", "viewer_token", "map_token")


class Settings(BaseSettings):
    """Everything an operator can set; each field is also the ``XVIZ_<NAME>`` environment variable."""

    model_config = SettingsConfigDict(env_prefix="XVIZ_", frozen=True, extra="forbid")

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        # Flags (given as arguments) over the environment over the file.
        return init_settings, env_settings, TomlConfigSettingsSource(settings_cls)

    data_dir: Annotated[list[str], NoDecode] = Field(
        default_factory=list,
        description="directory to serve: every log and dataset found under it (XVIZ logs in the reference layout, "
        "KITTI raw drives, Waymo segments, VISTA traces, ROS bags and MCAP files; one file alone is --dataset), or "
        "an object store prefix s3://BUCKET/PREFIX (configured by the AWS variables and files); repeat for more "
        "(env: one, or a JSON list); default: a built-in demo log",
    )
    dataset: list[str] = Field(
        default_factory=list,
        description="serve a raw dataset, KIND:PATH (e.g. kitti:/data/2011_09_26_drive_0001_sync), converted on "
        "demand; repeat for more (env: a JSON list)",
    )
    state_dir: Path | None = Field(
        default=None,
        description="directory where the server keeps its state: the catalog of logs (catalog.sqlite3), so that a "
        "restart lists every log at once, and the logs' MCAP files to seek in (files/); default: none, the catalog is "
        "kept in memory and built again at each start, the files in a temporary folder",
    )
    files_gb: float = Field(
        default=4,
        gt=0,
        description="most GB the logs' MCAP files to seek in (files/ under --state-dir, else a temporary folder) "
        "may take: once a new file puts them over, the least recently asked for are removed, never one being read",
    )
    catalog_poll: float = Field(
        default=2,
        gt=0,
        description="seconds between looks for logs added, changed or removed under a --data-dir directory "
        "(folders whose modification time changed); each look also compares the versions of the next 1000 logs in name order",
    )
    catalog_store_poll: float = Field(
        default=60,
        gt=0,
        description="seconds between listings of an s3:// --data-dir for logs added, changed or removed",
    )
    image_max_width: int = Field(
        default=DEFAULT_IMAGE_WIDTH, ge=16, description="camera images of raw datasets are scaled down to this width"
    )
    host: str = Field(default="127.0.0.1", description="address to listen on (0.0.0.0 for every interface)")
    port: int = Field(default=3000, ge=0, le=65535, description="TCP port for WebSocket and HTTP")
    cache_mb: float = Field(default=512, gt=0, description="size of the frame cache shared by all sessions, MB")
    preload_mb: float = Field(
        default=64,
        ge=0,
        description="read a log on local disk whose frames take at most this many MB into the frame "
        "cache when a session first opens it, so that seeking in it does not wait for the disk (0: never; at most half of cache_mb)",
    )
    max_sessions: int = Field(default=256, ge=1, description="connections beyond this are refused with HTTP 503")
    max_message_kb: int = Field(default=1024, ge=1, description="largest message a client may send, KB")
    idle_timeout: float = Field(
        default=60, gt=0, description="close a connection whose client stops answering keepalive pings for this long, s"
    )
    compression: bool = Field(
        default=False, description="offer permessage-deflate (costly for point clouds; for JSON over slow links)"
    )
    read_ahead: int = Field(default=4, ge=1, description="frames a streaming session loads ahead of the socket")
    store_read_ahead: int = Field(
        default=8, ge=1, description="GETs a streaming session keeps in flight to an object store"
    )
    store_read_ahead_mb: float = Field(
        default=32, gt=0, description="most MB of frames a streaming session has in flight from an object store"
    )
    store_timeout: float = Field(
        default=30, gt=0, description="seconds an object store request may take, connecting to last byte"
    )
    store_retries: int = Field(
        default=3, ge=0, description="times a failed object store GET (5xx, timeout, lost connection) is tried again"
    )
    lookback: int = Field(
        default=100, ge=1, description="most frames a point-in-time query merges to find a complete state"
    )
    validate_frames: bool = Field(
        default=False, description="check every frame against the XVIZ schema when first loaded"
    )
    ingest_token: str | None = Field(
        default=None,
        description="token that live sources must give to push to /ingest/NAME (Authorization: Bearer or "
        "?token=); without one, only loopback sources are accepted. A flag shows in ps: prefer the variable or "
        "--ingest-token-file",
    )
    ingest_token_file: Path | None = Field(
        default=None,
        description="read --ingest-token from this file (unlike a flag, it is not shown to other users by ps)",
    )
    max_ingest_mb: float = Field(default=64, gt=0, description="largest message a live source may push, MB")
    detail: Literal["auto", "off"] = Field(
        default="auto",
        description="auto: each session gets the level of detail its link carries (thinned point clouds, smaller "
        "images), measured as it goes; off: every session gets every byte",
    )
    live_queue: int = Field(
        default=32, ge=1, description="updates a live viewer may fall behind before the oldest are dropped"
    )
    live_lag_timeout: float = Field(
        default=30, gt=0, description="disconnect a live viewer that keeps dropping updates for this long, s"
    )
    live_from: Path | None = Field(
        default=None, description="replay this static log as a live feed named after its folder"
    )
    rate: float = Field(default=1.0, gt=0, description="playback rate of --live-from (1 is real time)")
    loop: bool = Field(default=False, description="replay --live-from over and over")
    record: Path | None = Field(default=None, description="record every live feed as a static log under this directory")
    record_rotate_mb: float = Field(
        default=1024, gt=0, description="start a new recording of a feed past this size, MB"
    )
    record_max_mb: float | None = Field(
        default=None, gt=0, description="record at most this much in all, MB (default: no cap)"
    )
    record_min_free_mb: float = Field(
        default=1024, ge=0, description="stop recording when the disk has less free space than this, MB"
    )
    log_format: Literal["text", "json"] = Field(default="text", description="log lines as text or as JSON objects")
    certfile: Path | None = Field(default=None, description="TLS certificate (PEM) to serve wss:// and https://")
    keyfile: Path | None = Field(default=None, description="TLS private key (PEM) for --certfile")
    viewer_token: str | None = Field(
        default=None,
        description="token that viewers must give (?token= or Authorization: Bearer) to open a session or list logs. "
        "A flag shows in ps: prefer the variable or --viewer-token-file",
    )
    viewer_token_file: Path | None = Field(
        default=None,
        description="read --viewer-token from this file (unlike a flag, it is not shown to other users by ps)",
    )
    protect_metrics: bool = Field(
        default=False, description="require the viewer token on GET /metrics too (/healthz always answers)"
    )
    map_token: str | None = Field(
        default=None,
        description="Mapbox access token for the built-in viewer's base map (without one it draws no map); "
        "handed to the pages of viewers that give the viewer token, if one is set",
    )
    broker: str | None = Field(
        default=None,
        description="share live feeds between replicas through this Redis, redis://[:PASSWORD@]HOST:PORT/DB "
        "(rediss:// for TLS); its password is never shown. Needs the extra: pip install 'xviz-server[broker]'",
    )
    broker_ttl: float = Field(
        default=10, gt=0, description="a feed whose replica stops renewing it for this long leaves other replicas, s"
    )
    broker_max_mb: float = Field(default=32, gt=0, description="most bytes of updates kept in the broker per feed, MB")
    frame_ancestors: list[str] = Field(
        default_factory=list,
        description="origins whose pages may show the viewer page in a frame, e.g. https://ops.example.com, or 'self'; "
        "repeat for more (default: none, the page is never framed)",
    )
    allowed_origins: list[str] = Field(
        default_factory=list,
        description="browser origins allowed to connect, e.g. https://viewer.example.com; repeat for more "
        "(default: any; clients that send no Origin, like scripts, are always allowed)",
    )

    @field_validator("data_dir", mode="before")
    @classmethod
    def _data_dirs(cls, value: Any) -> Any:
        """One directory or URL, or several: a list, or a JSON list in the environment."""
        if value is None:
            return []
        if isinstance(value, str) and value.startswith("["):
            return orjson.loads(value)
        if isinstance(value, (str, os.PathLike)):
            return [os.fspath(value)]
        return [os.fspath(item) for item in value] if isinstance(value, (list, tuple)) else value

    @field_validator(*SECRETS)
    @classmethod
    def _not_empty(cls, value: str | None, info: ValidationInfo) -> str | None:
        """A token that is set holds something: an empty one would open viewing but close ingest to everyone."""
        if value is not None and not value.strip():
            raise ValueError(
                f"is empty (XVIZ_{str(info.field_name).upper()}= or a blank flag): give a token, or leave it unset for none"
            )
        return value

    @field_validator("frame_ancestors")
    @classmethod
    def _frame_ancestors(cls, value: list[str]) -> list[str]:
        """Sources of a Content-Security-Policy: nothing that could end the directive or add another."""
        for origin in value:
            if not _FRAME_ANCESTOR.fullmatch(origin):
                raise ValueError(f"{origin!r} is not 'self' or an origin like https://ops.example.com")
        return value

    @model_validator(mode="before")
    @classmethod
    def _read_token_files(cls, data: Any) -> Any:
        """Take ``<name>_token`` from ``<name>_token_file`` when that is given."""
        if not isinstance(data, dict):
            return data
        for secret in SECRETS:
            source = data.get(f"{secret}_file")
            if source is None:
                continue
            if data.get(secret) is not None:
                raise ConfigError(f"give --{secret.replace('_', '-')} or --{secret.replace('_', '-')}-file, not both")
            data = {**data, secret: _read_token(Path(source))}
        return data

    @model_validator(mode="after")
    def _check_combinations(self) -> Settings:
        if self.keyfile is not None and self.certfile is None:
            raise ConfigError(f"--keyfile {self.keyfile} without --certfile: give the certificate too (or neither)")
        if self.broker is not None and urlsplit(self.broker).scheme not in ("redis", "rediss", "unix"):
            raise ConfigError(f"--broker {redact_password(self.broker)}: give a redis://, rediss:// or unix:// URL")
        if self.protect_metrics and self.viewer_token is None:
            raise ConfigError("--protect-metrics needs a viewer token (--viewer-token or --viewer-token-file)")
        return self


def _read_token(path: Path) -> str:
    """The token held by ``path``: its first line, without surrounding white space."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read the token file {path}: {getattr(exc, 'strerror', None) or exc}") from None
    token = text.strip()
    if not token or "\n" in token:
        raise ConfigError(f"the token file {path} must hold one line, the token")
    return token


def load_settings(config: Path | None = None, **flags: Any) -> Settings:
    """Settings from ``flags``, the environment, and the TOML file ``config`` (if any), in that order.

    Raises :class:`pydantic.ValidationError` for a wrong or unknown value,
    :class:`FileNotFoundError` if ``config`` does not exist.
    """
    if config is None:
        return Settings(**flags)
    if not Path(config).is_file():
        raise FileNotFoundError(f"configuration file {config} not found")

    class FromFile(Settings):
        model_config = SettingsConfigDict(**{**Settings.model_config, "toml_file": config})

    return FromFile(**flags)
