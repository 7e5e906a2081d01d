"""A frame's Foxglove messages: the converted ones and, for a log read from a recording, the original ones.

The converted messages of a frame are all at its time; the original
messages of a frame are those the file recorded from its time to the next
frame's (see :meth:`~xviz_server.logs.Log.original_messages`). Both come
from the frame cache, made once for every client; here they are only put in
time order, the payloads left where the cache keeps them.

A log's channels depend on its first frame too (its origin, the kinds of
its time series' values): :func:`log_plan` makes them.
"""

from __future__ import annotations

from operator import itemgetter

from ..exceptions import XVIZError
from ..levels import FULL, Level
from ..logs import Log
from ..records import unpack
from .translate import CONVERTED, Plan, convert, plan, read_survey, survey

__all__ = ["Message", "frame_messages", "log_plan", "SURVEY"]

#: The frame cache's name for what a log's first frame tells (see :meth:`~xviz_server.logs.Log.derived`).
SURVEY = "foxglove-survey"

#: A message as (channel id, log time in ns, payload).
Message = tuple[int, int, memoryview]


async def frame_messages(
    log: Log, plan: Plan, number: int, level: Level = FULL
) -> tuple[list[Message], list[XVIZError]]:
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


async def log_plan(log: Log) -> Plan:
    """The Foxglove channels of ``log`` (see :func:`~xviz_server.foxglove.translate.plan`), with what its first frame
    tells (:func:`~xviz_server.foxglove.translate.survey`, made once and kept in the frame cache); a first frame that
    cannot be read leaves the log without an origin, its time series as numbers unless their metadata says."""
    first = None
    if len(log.index.frames):
        try:
            first = read_survey(await log.derived(int(log.index.frames[0]), SURVEY, survey))
        except XVIZError:
            pass
    return plan(log.metadata, log.originals, first)
