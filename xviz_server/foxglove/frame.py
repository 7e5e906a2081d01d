"""A frame's Foxglove messages: the converted ones and, for a log read from a recording, the original ones.

The converted messages of a frame are all at its time; the original
messages of a frame are those the file recorded from its time to the next
frame's (see :meth:`~xviz_server.logs.Log.original_messages`). Both come
from the frame cache, made once for every client; here they are only put in
time order, the payloads left where the cache keeps them.
"""

from __future__ import annotations

from operator import itemgetter

from ..exceptions import XVIZError
from ..levels import FULL, Level
from ..logs import Log
from ..records import unpack
from .convert import CONVERTED, Plan, convert

__all__ = ["Message", "frame_messages"]

#: A message as (channel id, log time in ns, payload).
Message = tuple[int, int, memoryview]


async def frame_messages(log: Log, plan: Plan, number: int, level: Level = FULL) -> tuple[list[Message], list[XVIZError]]:
    """The messages of frame ``number`` of ``log`` on the channels of ``plan``, in time order (at one time, the
    converted ones first), the converted ones at ``level`` of detail, and why the part that could not be had is
    missing: a converted frame that cannot be read or converted, original messages that cannot be read (each a
    :class:`~xviz_server.exceptions.FrameError` naming the frame)."""
    errors: list[XVIZError] = []
    converted: list[Message] = []
    try:
        converted = list(unpack(await log.derived(number, CONVERTED, convert, plan, level=level)))
    except XVIZError as exc:
        errors.append(exc)
    if not plan.originals:
        return converted, errors
    try:
        packed = await log.original_messages(number)
    except XVIZError as exc:
        errors.append(exc)
        return converted, errors
    originals = [(plan.originals[topic], time, payload) for topic, time, payload in unpack(packed)]
    return sorted([*converted, *originals], key=itemgetter(1)), errors
