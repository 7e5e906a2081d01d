"""The TOML file that tells how a bag becomes XVIZ (the "configurable extractors").

Every key is optional; without a file, or for what it leaves out, the
default mapping applies::

    topics = ["/velodyne_points", "/camera/image_raw", "/tf", "/fix"]  # only these (default: all)
    exclude = ["/diagnostics"]     # never these
    vehicle_frame = "base_link"    # the frame points are drawn in (default: base_link, else the pose's)
    fixed_frame = "map"            # with a transform tree: the pose is vehicle_frame in this frame (default: its root)
    pose = "/tf"                   # "/tf", a topic (Odometry, PoseStamped, NavSatFix), or "none"
    clock = "/velodyne_points"     # one frame per message of this topic (default: the densest cloud)
    rate = 10.0                    # or frames at this rate, Hz, over the bag's span
    staleness = 1.0                # seconds a message stays current after it was recorded
    image_max_width = 640          # camera images are scaled down to this width (default: --image-max-width)
    intensity_scale = 0.01         # multiplies point intensities before colouring

    [streams."/velodyne_points"]
    name = "/lidar/points"         # the stream's name (default: the topic's)
    color = "intensity"            # clouds: auto, rgb, intensity or none
    style = { radius_pixels = 2 }  # the stream's style (XVIZ stream_style properties)
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any, Literal

import pydantic

from ...exceptions import DatasetError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = ["RosConfig", "StreamConfig", "load_config"]


class _Strict(pydantic.BaseModel):
    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)


class StreamConfig(_Strict):
    """How one topic's stream is named, coloured and styled."""

    name: str | None = pydantic.Field(default=None, pattern=r"^/")
    color: Literal["auto", "rgb", "intensity", "none"] = "auto"
    style: dict[str, Any] | None = None


class RosConfig(_Strict):
    """The choices of the file; see the module documentation."""

    topics: list[str] | None = None
    exclude: list[str] = []
    vehicle_frame: str | None = None
    fixed_frame: str | None = None
    pose: str | None = None
    clock: str | None = None
    rate: float | None = pydantic.Field(default=None, gt=0, le=1000)
    staleness: float = pydantic.Field(default=1.0, gt=0)
    image_max_width: int | None = pydantic.Field(default=None, ge=16)
    intensity_scale: float | None = pydantic.Field(default=None, gt=0)
    streams: dict[str, StreamConfig] = {}

    def stream(self, topic: str) -> StreamConfig:
        """The settings of ``topic``'s stream (the defaults if the file has none)."""
        return self.streams.get(topic, StreamConfig())

    def wants(self, topic: str) -> bool:
        """Whether ``topic`` is to be mapped."""
        return topic not in self.exclude and (self.topics is None or topic in self.topics)


def load_config(path: str | Path | None) -> RosConfig:
    """The configuration in the TOML file ``path``; the defaults for ``None``.

    Raises :class:`~xviz_server.exceptions.DatasetError` naming the file and
    the key that is wrong.
    """
    if path is None:
        return RosConfig()
    path = Path(path)
    try:
        document = tomllib.loads(path.read_text("utf-8"))
    except OSError as exc:
        raise DatasetError(f"{path}: {exc.strerror or exc}", path=path) from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise DatasetError(f"{path}: not TOML: {exc}", path=path) from None
    try:
        return RosConfig.model_validate(document)
    except pydantic.ValidationError as exc:
        problems = "; ".join(f"{'.'.join(str(p) for p in e['loc'])}: {e['msg']}" for e in exc.errors())
        raise DatasetError(f"{path}: {problems}", path=path) from None
