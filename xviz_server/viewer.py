"""The built-in viewer: the page at ``/`` and its assets, over HTTP.

``scripts/build-viewer.sh`` bundles the page (``viewer/`` in the repository:
streetscape.gl in a small React application) into :data:`STATIC_DIR`:
``index.html`` and content-hashed assets, each with a gzip (``.gz``) and a
brotli (``.br``) copy. :class:`ViewerPage` answers:

* ``GET /`` from a browser, one whose ``Accept`` header names ``text/html``:
  ``index.html``, ``Cache-Control: no-cache``, with the page's settings in
  it (:meth:`ViewerPage.page_settings`); other clients get ``None`` and so
  the JSON catalog, as before the viewer existed. Without a bundle, a
  browser is told in one line how to build it.
* ``GET /<hashed asset>``: the asset, ``immutable`` for a year, compressed
  as the client's ``Accept-Encoding`` allows.

The page connects its WebSocket to the same host and port, like any viewer.
It is sent with a Content-Security-Policy (:func:`content_security_policy`):
scripts, styles and fonts of the bundle only (no inline script, no eval),
connections to this server and to the base map's origins
(:data:`MAP_ORIGINS`), and no framing but by the origins the operator
allows. Every HTTP answer of the server carries :data:`HEADERS`.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Sequence
from http import HTTPStatus
from pathlib import Path
from urllib.parse import urlsplit

import orjson
from websockets.asyncio.server import ServerConnection
from websockets.http11 import Request, Response

from .auth import token_matches
from .work import Workers

__all__ = [
    "STATIC_DIR",
    "HEADERS",
    "MAP_ORIGINS",
    "STYLE_HASHES",
    "ViewerPage",
    "content_security_policy",
    "wants_html",
]

#: Where ``scripts/build-viewer.sh`` writes the bundle.
STATIC_DIR = Path(__file__).with_name("viewer_static")

#: Names of the bundle's assets: the hash in the name changes with the content.
ASSET = re.compile(r"/((?:viewer|asset)-[A-Z0-9]+\.(css|js|png|svg|woff2?))")

CONTENT_TYPES = {
    "html": "text/html; charset=utf-8",
    "css": "text/css; charset=utf-8",
    "js": "text/javascript; charset=utf-8",
    "png": "image/png",
    "svg": "image/svg+xml",
    "woff": "font/woff",
    "woff2": "font/woff2",
}

#: Content codings of the precompressed copies, best first, with their file suffix.
ENCODINGS = (("br", ".br"), ("gzip", ".gz"))

#: Where ``index.html`` takes the page's settings: a JSON script element the page reads.
SETTINGS_SLOT = b"<!--settings-->"

#: The origins the base map (mapbox-gl, with a map token) loads its style, tiles, sprites and glyphs from,
#: and reports to: those Mapbox documents for a Content-Security-Policy.
MAP_ORIGINS = ("https://api.mapbox.com", "https://*.tiles.mapbox.com", "https://events.mapbox.com")

#: The inline styles the bundle's libraries insert, by the hash of their text (``style-src``): the empty
#: ``<style>`` element emotion fills through the CSSOM (which no policy restricts), and the rules of
#: react-virtualized's AutoSizer (``detectElementResize``), which sizes the 3D view. A library that changes
#: them is refused by the browser, and the browser tests say so.
STYLE_HASHES = (
    "'sha256-47DEQpj8HBSa+/TImW+5JCeuQeRkm5NMpJWZG3hSuFU='",
    "'sha256-deDIoPlRijnpfbTDYsK+8JmDfUBmpwpnb0L/SUV8NeU='",
)

#: Headers of every HTTP answer: no guessing of content types (a JSON catalog is never run as a script),
#: and no page address (the viewer token, on the page's first load) sent to other origins.
HEADERS = {"X-Content-Type-Options": "nosniff", "Referrer-Policy": "strict-origin"}

NOT_BUILT = (
    "the viewer is not built: run scripts/build-viewer.sh (needs node and npm), or open /api/logs for the catalog\n"
)


def content_security_policy(frame_ancestors: Sequence[str] = ()) -> str:
    """The viewer page's Content-Security-Policy; ``frame_ancestors``: the origins that may show it in a frame
    (none by default).

    mapbox-gl runs its workers from ``blob:`` URLs and draws images it
    fetched (``blob:``, ``data:``); the bundle's styles are its CSS file and
    the few inline ones of :data:`STYLE_HASHES` (React sets element styles
    through the DOM, which no policy restricts).
    """
    maps, ancestors = " ".join(MAP_ORIGINS), " ".join(frame_ancestors) or "'none'"
    return "; ".join(
        [
            "default-src 'none'",
            "script-src 'self'",
            f"style-src 'self' {' '.join(STYLE_HASHES)}",
            f"img-src 'self' data: blob: {maps}",
            "font-src 'self' data:",
            f"connect-src 'self' {maps}",
            "worker-src blob:",
            "child-src blob:",
            "base-uri 'none'",
            "form-action 'none'",
            f"frame-ancestors {ancestors}",
        ]
    )


def wants_html(request: Request) -> bool:
    """Whether the client asks for a page (a browser) rather than data."""
    return "text/html" in request.headers.get("Accept", "")


def accepted_encodings(request: Request) -> set[str]:
    """The content codings ``Accept-Encoding`` allows (those not given ``q=0``)."""
    accepted = set()
    for item in request.headers.get("Accept-Encoding", "").split(","):
        coding, *params = (part.strip() for part in item.split(";"))
        quality = next((param[2:] for param in params if param.startswith("q=")), "1")
        try:
            if coding and float(quality) > 0:
                accepted.add(coding.lower())
        except ValueError:
            continue
    return accepted


class ViewerPage:
    """Answers HTTP requests for the viewer page from the bundle in ``directory``.

    ``map_token`` (a Mapbox access token) is handed to the page, which then
    draws a base map; with a ``viewer_token``, only to requests that give it.
    ``frame_ancestors``: the origins that may show the page in a frame.
    """

    def __init__(
        self,
        directory: Path,
        workers: Workers,
        map_token: str | None = None,
        viewer_token: str | None = None,
        frame_ancestors: Sequence[str] = (),
    ) -> None:
        self.directory = directory
        self.workers = workers
        self.map_token = map_token
        self.viewer_token = viewer_token
        self.policy = content_security_policy(frame_ancestors)

    def page_settings(self, request: Request) -> dict[str, str]:
        """What the page is told: ``mapToken`` when there is one and the request may have it."""
        if self.map_token is None or (self.viewer_token and not token_matches(request, self.viewer_token)):
            return {}
        return {"mapToken": self.map_token}

    async def respond(self, connection: ServerConnection, request: Request) -> Response | None:
        """The response to ``request`` if it is for the page or one of its assets, else ``None``."""
        path = urlsplit(request.path).path
        if path == "/":
            if not wants_html(request):
                return None
            index = await self.workers.io(_read, self.directory / "index.html")
            if index is None:
                return _respond(connection, HTTPStatus.NOT_FOUND, NOT_BUILT.encode(), "text/plain; charset=utf-8", {})
            page = index.replace(SETTINGS_SLOT, _settings_element(self.page_settings(request)))
            headers = {"Cache-Control": "no-cache", "Vary": "Accept", "Content-Security-Policy": self.policy}
            return _respond(connection, HTTPStatus.OK, page, CONTENT_TYPES["html"], headers)
        match = ASSET.fullmatch(path)
        if match is None:
            return None
        name, extension = match.groups()
        accepted = accepted_encodings(request)
        candidates = [(coding, name + suffix) for coding, suffix in ENCODINGS if coding in accepted]
        for coding, file_name in [*candidates, (None, name)]:
            body = await self.workers.io(_read, self.directory / file_name)
            if body is not None:
                headers = {"Cache-Control": "public, max-age=31536000, immutable", "Vary": "Accept-Encoding"}
                if coding is not None:
                    headers["Content-Encoding"] = coding
                return _respond(connection, HTTPStatus.OK, body, CONTENT_TYPES[extension], headers)
        return None


def _settings_element(settings: dict[str, str]) -> bytes:
    """``settings`` as a JSON script element; ``<``, ``>`` and ``&`` escaped so that no value can end it."""
    text = orjson.dumps(settings).replace(b"<", b"\\u003c").replace(b">", b"\\u003e").replace(b"&", b"\\u0026")
    return b'<script id="xviz-settings" type="application/json">' + text + b"</script>"


def _read(path: Path) -> bytes | None:
    """The bytes of ``path``, or ``None`` if it is not there."""
    try:
        return path.read_bytes()
    except (FileNotFoundError, NotADirectoryError, IsADirectoryError):
        return None


def _respond(
    connection: ServerConnection, status: HTTPStatus, body: bytes, content_type: str, headers: dict[str, str]
) -> Response:
    response = connection.respond(status, "")
    del response.headers["Content-Type"], response.headers["Content-Length"]
    response.headers["Content-Type"] = content_type
    response.headers["Content-Length"] = str(len(body))
    response.headers.update(headers)
    return dataclasses.replace(response, body=body)
