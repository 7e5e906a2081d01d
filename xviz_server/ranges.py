"""Which part of a file a GET asks for: byte ranges and conditional requests (RFC 9110), without I/O.

:func:`decide` reads a request's ``Range``, ``If-Range``, ``If-Match``,
``If-None-Match`` and ``If-Modified-Since`` headers against what is known of
the file (:class:`Representation`: its size, strong ETag and modification
time) and says what to answer (:class:`Answer`): the status, the bytes to
send (an offset and a length) and the headers that describe them. The
caller sends the bytes.

* ``If-Match`` that names no current ETag (nor ``*``): ``412``.
* ``If-None-Match`` that names the current ETag (weak comparison, or
  ``*``), or, without ``If-None-Match``, ``If-Modified-Since`` not before
  the file's time: ``304``, no body.
* One range, ``bytes=FIRST-LAST``, ``bytes=FIRST-`` or ``bytes=-SUFFIX``:
  ``206`` with ``Content-Range``, its end cut to the file's; a range that
  starts past the end, a zero suffix, ``LAST < FIRST`` or a ``bytes`` range
  that cannot be read: ``416`` with ``Content-Range: bytes */SIZE``.
* ``If-Range`` whose ETag or date is not the file's current one, a range
  unit other than ``bytes`` and several ranges at once (not served: no
  multipart answers): the range is ignored, the whole file is answered.

Every answer carries ``Accept-Ranges: bytes``, ``ETag`` and ``Last-Modified``.

A header given on several lines is read as one, its values joined by commas
(RFC 9110, section 5.3): two ``Range`` lines are several ranges, two
``If-None-Match`` lines one list of tags.
"""

from __future__ import annotations

import email.utils
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from http import HTTPStatus

__all__ = ["Representation", "Answer", "decide"]

_RANGE = re.compile(r"bytes=(\d*)-(\d*)")
#: Digits a range's bound may have: more is no offset in any file this serves.
_MAX_DIGITS = 18


@dataclass(frozen=True)
class Representation:
    """What an answer tells of a file: its length in bytes, its strong ETag (quoted) and modification time (epoch seconds)."""

    size: int
    etag: str
    modified: float

    @property
    def last_modified(self) -> str:
        """The modification time as an HTTP date."""
        return email.utils.formatdate(self.modified, usegmt=True)


@dataclass(frozen=True)
class Answer:
    """What to answer: the status, the file's bytes ``[offset, offset + length)`` as body, and the headers."""

    status: HTTPStatus
    offset: int = 0
    length: int = 0
    headers: dict[str, str] = field(default_factory=dict)


def decide(headers: Iterable[tuple[str, str]], file: Representation) -> Answer:
    """The answer to a GET (or HEAD) of ``file`` with the request's header lines ``headers`` (names in any case)."""
    lowered: dict[str, str] = {}
    for name, value in headers:
        key = name.lower()
        lowered[key] = f"{lowered[key]}, {value}" if key in lowered else value
    common = {"Accept-Ranges": "bytes", "ETag": file.etag, "Last-Modified": file.last_modified}
    if (wanted := lowered.get("if-match")) is not None and not _matches(wanted, file.etag, strong=True):
        return Answer(HTTPStatus.PRECONDITION_FAILED, headers=common)
    if (cached := lowered.get("if-none-match")) is not None:
        if _matches(cached, file.etag, strong=False):
            return Answer(HTTPStatus.NOT_MODIFIED, headers=common)
    elif (since := _date(lowered.get("if-modified-since"))) is not None and int(file.modified) <= since:
        return Answer(HTTPStatus.NOT_MODIFIED, headers=common)
    whole = Answer(HTTPStatus.OK, 0, file.size, common)
    asked = lowered.get("range")
    if asked is None or not asked.strip().lower().startswith("bytes=") or "," in asked:
        return whole
    if (condition := lowered.get("if-range")) is not None and not _current(condition, file):
        return whole
    span = _span(asked.strip().replace(" ", ""), file.size)
    if span is None:
        return Answer(
            HTTPStatus.REQUESTED_RANGE_NOT_SATISFIABLE, headers={**common, "Content-Range": f"bytes */{file.size}"}
        )
    first, last = span
    return Answer(
        HTTPStatus.PARTIAL_CONTENT,
        first,
        last - first + 1,
        {**common, "Content-Range": f"bytes {first}-{last}/{file.size}"},
    )


def _span(text: str, size: int) -> tuple[int, int] | None:
    """The first and last byte ``bytes=...`` asks for in a file of ``size`` bytes, or ``None`` when it cannot be served."""
    found = _RANGE.fullmatch(text.lower())
    if found is None or (not found[1] and not found[2]) or max(len(found[1]), len(found[2])) > _MAX_DIGITS:
        return None
    if not found[1]:  # the last SUFFIX bytes
        suffix = int(found[2])
        return None if suffix == 0 or size == 0 else (max(0, size - suffix), size - 1)
    first = int(found[1])
    last = int(found[2]) if found[2] else size - 1
    if last < first or first >= size:
        return None
    return first, min(last, size - 1)


def _tags(text: str) -> list[str]:
    """The entity tags of an ``If-Match``-like header, as written (with ``W/`` when weak)."""
    return [tag.strip() for tag in text.split(",") if tag.strip()]


def _matches(text: str, etag: str, *, strong: bool) -> bool:
    """Whether a list of entity tags (or ``*``) names ``etag``; a weak tag never matches strongly."""
    for tag in _tags(text):
        if tag == "*" or tag == etag or (not strong and tag.removeprefix("W/") == etag):
            return True
    return False


def _current(condition: str, file: Representation) -> bool:
    """Whether an ``If-Range`` names the file as it is: its ETag (strongly), or exactly its date."""
    condition = condition.strip()
    if condition.startswith('"'):
        return condition == file.etag
    return _date(condition) == int(file.modified)


def _date(text: str | None) -> int | None:
    """An HTTP date in epoch seconds, or ``None`` when absent or unreadable."""
    if not text:
        return None
    try:
        return int(email.utils.parsedate_to_datetime(text).timestamp())
    except (TypeError, ValueError, IndexError, OverflowError):
        return None
