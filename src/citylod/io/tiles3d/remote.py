"""Tilesets served over HTTP(S), read file by file as a 3D Tiles client reads them.

``open_tileset("https://host/data/tileset.json")`` reads the tileset JSON, then each tile's content when a view
needs it, with one GET per file (urllib; HTTP keep-alive is not needed at these request rates). Content URIs are
resolved as a browser resolves them (relative, root-relative ``/x``, or absolute), and must stay on the same
server (scheme, host and port): a tileset cannot make citylod fetch from anywhere else, and a redirect to
another server is refused too. A URI's own query string (``?v=2``, a session) is kept, and the tileset URL's
(an access token) is added to every request, as CesiumJS's resources pass their query parameters on.

Every request has a time-out and a size cap; a busy server (429, 502–504) is asked again after a pause, up to
four times; an HTTP error, a refused connection or a time-out is one :class:`~citylod.core.errors.InputError`
naming the URL (keys and tokens in it shown as ``…``). Files are kept in a disk cache as HTTP allows
(:mod:`citylod.io.tiles3d.http_cache`), so a tileset opened again is read from disk or revalidated.

**Cesium ion.** ``ion:ASSET_ID`` opens a 3D Tiles asset on Cesium ion as CesiumJS's ``IonResource`` and
cesium-native's ion loader do: one GET of ``{api}/v1/assets/{id}/endpoint?access_token={token}`` (the token from
``CESIUM_ION_TOKEN``, the API from ``CESIUM_ION_API``, default ``https://api.cesium.com``) answers the tileset's
URL and a short-lived token for its server, sent as ``Authorization: Bearer`` with every request there. When
that server answers 401 (the token expired), the endpoint is asked again and the request repeated once. An
asset the endpoint declares external (``externalType`` 3DTILES, Google's Photorealistic 3D Tiles through ion)
is opened at its ``options.url``, which carries its own key. The endpoint's attributions are kept
(:attr:`Remote.attributions`): ion's terms ask clients to show them.
"""

from __future__ import annotations

import contextlib
import html
import json
import os
import posixpath
import re
import sqlite3
import threading
import time
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Callable, Mapping
from pathlib import Path

from citylod._version import __version__
from citylod.core.errors import InputError, UnsafePathError
from citylod.io.tiles3d.archive3tz import MAX_ENTRY_BYTES
from citylod.io.tiles3d.http_cache import default_cache

__all__ = ["Remote", "is_ion", "is_url", "open_remote", "redact", "unfold_url"]

TIMEOUT_S = 30.0
_CHUNK = 1 << 20
ION_API = "https://api.cesium.com"
_ION = re.compile(r"ion:/{0,2}(\d+)/?")  # "ion://7" folded by pathlib is "ion:/7"


def is_ion(source: object) -> bool:
    """Whether ``source`` names a Cesium ion asset: ``ion:ASSET_ID`` (``ion://ASSET_ID`` too)."""
    return _ION.fullmatch(str(source)) is not None


def is_url(source: object) -> bool:
    """Whether ``source`` is an http(s) URL, also after ``pathlib.Path`` folded its ``//`` into ``/``, or a Cesium
    ion asset (:func:`is_ion`): a tileset read over the network either way."""
    return str(source).startswith(("http://", "https://", "http:/", "https:/")) or is_ion(source)


def unfold_url(source: object) -> str:
    """A URL as typed, after ``pathlib.Path`` folded its ``//`` (``https:/host`` → ``https://host``)."""
    s = str(source)
    for scheme in ("http:", "https:"):
        if s.startswith(scheme + "/") and not s.startswith(scheme + "//"):
            return scheme + "/" + s[len(scheme):]
    return s


class Remote:
    """A tileset on an HTTP(S) server; :meth:`read` fetches a file by its path on the server.

    ``root`` is a local stand-in path for the server's root (nothing is written there): the tileset's files get
    paths below it (a URI's query string kept in the last part of the name), so the reader's path checks work
    unchanged; :meth:`resolve` turns a content URI into such a path.
    """

    def __init__(self, url: str, timeout_s: float | None = None, headers: dict[str, str] | None = None,
                 renew: Callable[[], dict[str, str]] | None = None) -> None:
        url = unfold_url(url)
        parts = urllib.parse.urlsplit(url)
        if parts.scheme not in ("http", "https") or not parts.netloc:
            raise InputError("not an http(s) URL", url)
        path = parts.path or "/"
        if path.endswith("/"):
            path += "tileset.json"
        path = posixpath.normpath(path)  # "a/../b" as the server reads it, so the folder has no ".." in it
        if not path.startswith("/"):
            path = "/" + path
        self.url = url
        #: What the tileset is opened by again (a project keeps it): the URL, or ``ion:ID`` for an ion asset.
        self.source = url
        #: Credits the server asks clients to show (Cesium ion's attributions, as text).
        self.attributions: list[str] = []
        #: Sent with every request (an ion asset's ``Authorization``); ``renew`` replaces them after a 401.
        self.headers = dict(headers or {})
        self._renew = renew
        self._renew_lock = threading.Lock()
        self.scheme, self.netloc = parts.scheme, parts.netloc
        self.origin = f"{parts.scheme}://{parts.netloc}"
        # One opener for every request (the loader's threads share it: it keeps no state between requests).
        self._opener = urllib.request.build_opener(_SameServer(self.origin))
        self.query = parts.query
        self.timeout_s = TIMEOUT_S if timeout_s is None else timeout_s
        self.root = Path("/citylod-remote") / parts.scheme / parts.netloc.replace(":", "_")
        #: Where the tileset JSON stands under :attr:`root`.
        self.entry = self.root / path.lstrip("/")

    def resolve(self, base: Path, uri: str, source: str) -> Path:
        """The stand-in path of content ``uri`` referred to from folder ``base``; UnsafePathError when it is on
        another server."""
        parsed = urllib.parse.urlsplit(uri)
        if "\x00" in uri:
            raise UnsafePathError(f"content URI {uri!r} holds a NUL byte", source)
        if parsed.scheme or parsed.netloc:
            if (parsed.scheme, parsed.netloc) != (self.scheme, self.netloc):
                raise UnsafePathError(f"content URI {uri!r} is on another server than the tileset "
                                      f"({self.origin}); only that server is read", source)
        path = urllib.parse.unquote(parsed.path)
        if not path:
            raise UnsafePathError(f"content URI {uri!r} has no path", source)
        here = "/" + base.relative_to(self.root).as_posix() if base != self.root else "/"
        # As a browser resolves it: ".." stops at the server's root.
        full = "/" + posixpath.normpath(path if path.startswith("/") else posixpath.join(here, path)).lstrip("/")
        if full == "/":
            raise UnsafePathError(f"content URI {uri!r} names the server's root, not a file", source)
        target = self.root / full.lstrip("/")
        return target.with_name(f"{target.name}?{parsed.query}") if parsed.query else target

    def url_of(self, name: str) -> str:
        """The URL of the file ``name`` (its path on the server, relative to the root, its query at the end)."""
        path, _, query = name.partition("?")
        extra = [q for q in (query, self.query) if q]
        return f"{self.origin}/{urllib.parse.quote(path, safe='/')}" + (f"?{'&'.join(extra)}" if extra else "")

    def read(self, name: str) -> bytes:
        """The file's bytes; :class:`InputError` naming the URL when the server does not give them. A 401 with
        a ``renew`` callable renews the headers (once for all threads that saw the old ones) and asks again.
        The disk cache (:mod:`citylod.io.tiles3d.http_cache`) answers first where HTTP allows it."""
        url = self.url_of(name)
        shown = redact(url)
        cache = default_cache()
        kept = None
        try:
            kept = cache.get(shown) if cache is not None else None
        except sqlite3.Error:
            cache = None
        if kept is not None and kept.fresh:
            return kept.body
        ask = kept.validators() if kept is not None else {}
        try:
            body, headers = self._get_authorised(url, shown, ask)
        except _NotModified as answer:
            assert kept is not None and cache is not None
            with contextlib.suppress(sqlite3.Error):
                cache.refresh(shown, answer.headers)
            return kept.body
        if cache is not None:
            with contextlib.suppress(sqlite3.Error):
                cache.put(shown, body, headers)
        return body

    def _get_authorised(self, url: str, shown: str, ask: dict[str, str]) -> tuple[bytes, Mapping[str, str]]:
        sent = self.headers
        try:
            return _get(url, self._opener, self.timeout_s, {**sent, **ask}, shown)
        except _Unauthorised as exc:
            if self._renew is None:
                raise InputError("HTTP 401 Unauthorized", shown) from exc
        with self._renew_lock:
            if self.headers is sent:  # no other thread renewed them meanwhile
                self.headers = self._renew()
        try:
            return _get(url, self._opener, self.timeout_s, {**self.headers, **ask}, shown)
        except _Unauthorised as exc:
            raise InputError("HTTP 401 Unauthorized, also with a renewed token", shown) from exc

    def size(self, name: str) -> int:
        """0: a remote file's size is known once it is read (no HEAD request per tile)."""
        return 0



_SECRET = re.compile(r"(?i)([?&](?:key|api_?key|access_?token|token|signature|sig)=)[^&]*")


def redact(url: str) -> str:
    """``url`` as an error message may show it: the values of its keys and tokens replaced by ``…``."""
    return _SECRET.sub(r"\1…", url)


class _SameServer(urllib.request.HTTPRedirectHandler):
    """Follows a redirect only on the tileset's server (a renamed file, a trailing slash)."""

    def __init__(self, origin: str) -> None:
        super().__init__()
        self.origin = origin

    def redirect_request(self, req, fp, code, msg, headers, newurl):  # type: ignore[no-untyped-def]
        parts = urllib.parse.urlsplit(urllib.parse.urljoin(req.full_url, newurl))
        if f"{parts.scheme}://{parts.netloc}" != self.origin:
            raise InputError(f"the server redirects to {newurl}, another server than the tileset's", req.full_url)
        return super().redirect_request(req, fp, code, msg, headers, newurl)


class _Unauthorised(Exception):
    """HTTP 401 from the server: the caller may renew its token and ask again."""


class _NotModified(Exception):
    """HTTP 304 to a conditional request: the kept body is current (``headers``: the answer's, names in lower
    case)."""

    def __init__(self, headers: Mapping[str, str]) -> None:
        super().__init__("304")
        self.headers = headers


#: Answers that say "not now" rather than "no": asked again after a pause (the server's Retry-After, capped).
_RETRY_CODES = (429, 502, 503, 504)
#: Pauses before the second, third and fourth try, seconds (a server's Retry-After replaces one, up to 8 s).
RETRY_PAUSES_S = (0.5, 1.5, 4.0)


def _get(url: str, opener: urllib.request.OpenerDirector, timeout_s: float, headers: dict[str, str],
         name: str | None = None) -> tuple[bytes, Mapping[str, str]]:
    """The body of a GET of ``url``, size-capped; :class:`_Unauthorised` on 401, else InputError naming ``name``
    (default the URL) when the server does not give it. A busy or overloaded server (429, 502–504: Google's and
    ion's answer to a burst of tile requests) is asked again after :data:`RETRY_PAUSES_S`, then refused."""
    for pause in (*RETRY_PAUSES_S, None):
        try:
            return _get_once(url, opener, timeout_s, headers, name)
        except urllib.error.HTTPError as exc:
            if pause is None:
                raise InputError(f"HTTP {exc.code} {exc.reason}, {len(RETRY_PAUSES_S) + 1} times", name or url) from exc
            after = exc.headers.get("Retry-After", "") if exc.headers is not None else ""
            time.sleep(min(float(after), 8.0) if after.strip().isdigit() else pause)
    raise AssertionError("unreachable")


def _get_once(url: str, opener: urllib.request.OpenerDirector, timeout_s: float, headers: dict[str, str],
              name: str | None) -> tuple[bytes, Mapping[str, str]]:
    """One GET (:func:`_get`): the body and the answer's headers (names in lower case); raises the HTTPError of an answer in
    :data:`_RETRY_CODES`, and :class:`_NotModified` for a 304."""
    where = url if name is None else name
    request = urllib.request.Request(url, headers={"User-Agent": f"citylod/{__version__}",
                                                   "Accept-Encoding": "identity", **headers})
    try:
        with opener.open(request, timeout=timeout_s) as response:
            length = response.headers.get("Content-Length")
            if length is not None and length.isdigit() and int(length) > MAX_ENTRY_BYTES:
                raise InputError(f"the server announces {int(length):,} bytes (more than "
                                 f"{MAX_ENTRY_BYTES:,}); refused", where)
            chunks, total = [], 0
            while chunk := response.read(_CHUNK):
                total += len(chunk)
                if total > MAX_ENTRY_BYTES:
                    raise InputError(f"more than {MAX_ENTRY_BYTES:,} bytes; refused", where)
                chunks.append(chunk)
            return b"".join(chunks), {k.lower(): v for k, v in response.headers.items()}
    except urllib.error.HTTPError as exc:
        if exc.code == 304:
            raise _NotModified({k.lower(): v for k, v in (exc.headers.items() if exc.headers is not None else [])}) \
                from None
        if exc.code == 401:
            raise _Unauthorised() from exc
        if exc.code in _RETRY_CODES:
            raise
        raise InputError(f"HTTP {exc.code} {exc.reason}", where) from exc
    except urllib.error.URLError as exc:
        raise InputError(f"cannot reach the server ({exc.reason})", where) from exc
    except (TimeoutError, OSError) as exc:  # a read that stalls past the time-out, a reset connection
        raise InputError(f"no answer within {timeout_s:g} s ({exc})", where) from exc


def open_remote(source: str) -> Remote:
    """The :class:`Remote` of an http(s) URL, or of a Cesium ion asset ``ion:ID`` (module docstring)."""
    match = _ION.fullmatch(str(source))
    if match is None:
        return Remote(source)
    asset = int(match.group(1))
    token = os.environ.get("CESIUM_ION_TOKEN", "").strip()
    if not token:
        raise InputError("a Cesium ion asset needs an access token: set CESIUM_ION_TOKEN", source)
    api = os.environ.get("CESIUM_ION_API", ION_API).rstrip("/")
    endpoint = f"{api}/v1/assets/{asset}/endpoint?access_token={urllib.parse.quote(token, safe='')}"

    def ask() -> dict[str, object]:
        """The endpoint's answer (a new short-lived token each time)."""
        try:
            body = _get(endpoint, urllib.request.build_opener(), TIMEOUT_S, {}, name=source)[0]
        except _Unauthorised:
            raise InputError("Cesium ion refused the access token in CESIUM_ION_TOKEN (HTTP 401)", source) from None
        try:
            doc = json.loads(body)
        except ValueError as exc:
            raise InputError("Cesium ion's endpoint answer is not JSON", source) from exc
        if not isinstance(doc, dict):
            raise InputError("Cesium ion's endpoint answer is not a JSON object", source)
        kind = doc.get("externalType", doc.get("type"))
        if kind != "3DTILES":
            raise InputError(f"the asset is {kind!r} on Cesium ion, not a 3D Tiles tileset", source)
        return doc

    def access(doc: dict[str, object]) -> tuple[str, dict[str, str]]:
        """The tileset's URL and the headers its server wants."""
        if "externalType" in doc:
            options = doc.get("options")
            url = options.get("url") if isinstance(options, dict) else None
            headers: dict[str, str] = {}
        else:
            url, token = doc.get("url"), doc.get("accessToken")
            headers = {"Authorization": f"Bearer {token}"} if isinstance(token, str) and token else {}
        if not isinstance(url, str) or not is_url(url) or is_ion(url):
            raise InputError("Cesium ion's endpoint answer names no http(s) tileset URL", source)
        return url, headers

    doc = ask()
    url, headers = access(doc)
    remote = Remote(url, headers=headers, renew=lambda: access(ask())[1])
    remote.source = f"ion:{asset}"
    credits = doc.get("attributions")
    for item in credits if isinstance(credits, list) else []:
        text = item.get("html") if isinstance(item, dict) else None
        if isinstance(text, str):  # HTML: its text, as a credit line shows it
            remote.attributions.append(" ".join(html.unescape(re.sub(r"<[^>]*>", " ", text)).split()))
    return remote
