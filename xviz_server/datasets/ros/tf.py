"""The transform tree of a bag: ``/tf_static`` read once, ``/tf`` read around each frame's time.

Frame ids with and without a leading slash are the same frame (ROS 1 tf
allowed both). Dynamic transforms are interpolated at the time asked for
(translation linearly, rotation by slerp) between the samples recorded
around it; all times are record times, like every other topic's.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from .geometry import from_transform, interpolate

if TYPE_CHECKING:
    from .bag import Recording

__all__ = ["frame_name", "TransformTree", "Snapshot", "TF", "TF_TYPES"]

TF = "/tf"
#: The transform messages: ROS 2 and ROS 1 ``tf2_msgs``, ROS 1 ``tf`` (and Foxglove's FrameTransform(s)).
TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")
#: /tf messages read on each side of a time to find the samples around it.
_WINDOW = 16
#: /tf messages read at open to learn which frames /tf moves.
_SAMPLE = 200


def frame_name(frame_id: str) -> str:
    """A frame id without surrounding blanks and leading slashes."""
    return frame_id.strip().lstrip("/")


def _edges(message: object) -> list[tuple[str, str, np.ndarray]]:
    return [
        (frame_name(t.header.frame_id), frame_name(t.child_frame_id), from_transform(t.transform))
        for t in message.transforms  # type: ignore[attr-defined]
    ]


@dataclass
class Snapshot:
    """Every transform of the tree at one time."""

    parents: dict[str, tuple[str, np.ndarray]]

    def to_root(self, frame: str) -> tuple[str, np.ndarray]:
        """The root of ``frame``'s tree and the transform from ``frame`` to it."""
        transform, seen = np.eye(4), {frame}
        while frame in self.parents:
            parent, edge = self.parents[frame]
            if parent in seen:  # a cycle: a broken tree, stop at the loop
                break
            transform, frame = edge @ transform, parent
            seen.add(frame)
        return frame, transform

    def lookup(self, source: str, target: str) -> np.ndarray | None:
        """The transform taking points of frame ``source`` into frame ``target``; ``None`` if not connected."""
        source_root, source_to_root = self.to_root(source)
        target_root, target_to_root = self.to_root(target)
        if source_root != target_root:
            return None
        return np.linalg.inv(target_to_root) @ source_to_root


@dataclass
class TransformTree:
    """The static tree, which frames the dynamic topic moves, and snapshots at any time.

    Every topic of a transform type whose name ends in ``tf_static`` is
    static; the dynamic topic is ``/tf`` if the bag has it with transforms,
    else the first other topic of a transform type (``tf``, ``/tf2``).
    """

    bag: Recording
    staleness: int  # ns
    static: dict[str, tuple[str, np.ndarray]] = field(init=False)
    moving: dict[str, str] = field(init=False)
    #: The topic of the moving transforms, if the bag has one with messages.
    dynamic: str | None = field(init=False)

    def __post_init__(self) -> None:
        self.static = {}
        topics = self.bag.topics
        usable = [
            t for t, info in topics.items() if info.msgtype in TF_TYPES and len(info) and t not in self.bag.problems
        ]
        for topic in (t for t in usable if t.endswith("tf_static")):
            for _, message in self.bag.messages(topic, None, None):
                for parent, child, edge in _edges(message):
                    self.static[child] = (parent, edge)
        moving = [t for t in usable if not t.endswith("tf_static")]
        self.dynamic = TF if TF in moving else (moving[0] if moving else None)
        self.moving = {}
        if self.dynamic is not None:
            times = topics[self.dynamic].times
            for _, message in self.bag.messages(
                self.dynamic, int(times[0]), int(times[min(len(times), _SAMPLE) - 1]) + 1
            ):
                for parent, child, _ in _edges(message):
                    self.moving[child] = parent

    @property
    def has_tf(self) -> bool:
        return self.dynamic is not None

    @property
    def frames(self) -> set[str]:
        """Every frame the tree names."""
        parents = {parent for parent, _ in self.static.values()} | set(self.moving.values())
        return parents | self.static.keys() | self.moving.keys()

    def static_snapshot(self) -> Snapshot:
        """The tree of ``/tf_static`` alone."""
        return Snapshot(dict(self.static))

    def at(self, t: int) -> Snapshot:
        """The tree at ``t`` ns: static transforms and ``/tf`` interpolated (or the nearest sample within staleness)."""
        parents = dict(self.static)
        if self.dynamic is None:
            return Snapshot(parents)
        topic = self.bag.topics[self.dynamic]
        i = topic.at_or_before(t)
        first, last = max(i - _WINDOW, 0), min(i + _WINDOW, len(topic) - 1)
        before: dict[str, tuple[int, str, np.ndarray]] = {}
        after: dict[str, tuple[int, str, np.ndarray]] = {}
        for time, message in self.bag.messages(self.dynamic, int(topic.times[first]), int(topic.times[last]) + 1):
            for parent, child, edge in _edges(message):
                if time <= t:
                    before[child] = (time, parent, edge)
                elif child not in after:
                    after[child] = (time, parent, edge)
        for child in before.keys() | after.keys():
            a, b = before.get(child), after.get(child)
            if a is not None and b is not None and a[1] == b[1]:
                parents[child] = (a[1], interpolate(a[2], b[2], (t - a[0]) / (b[0] - a[0])))
            else:
                near = min((s for s in (a, b) if s is not None), key=lambda s: abs(s[0] - t))
                if abs(near[0] - t) <= self.staleness:
                    parents[child] = (near[1], near[2])
        return Snapshot(parents)
