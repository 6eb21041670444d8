"""Tilesets served over HTTP(S), read file by file as a 3D Tiles client reads them.

``open_tileset("https://host/data/tileset.json")`` reads the tileset JSON, then each tile's content when a view
needs it, with one GET per file (urllib; HTTP keep-alive is not needed at these request rates). Content URIs are
resolved as a browser resolves them (relative, root-relative ``/x``, or absolute), and must stay on the same
server (scheme, host and port): a tileset cannot make citylod fetch from anywhere else, and a redirect to
another server is refused too. A URI's own query string (``?v=2``, a session) is kept, and the tileset URL's
(an access token) is added to every request, as CesiumJS's resources pass their query parameters on.

Every request has a time-out and a size cap; an HTTP error, a refused connection or a time-out is one
:class:`~citylod.core.errors.InputError` naming the URL. Nothing is cached on disk: the renderer's memory cache
keeps what a view uses.
"""

from __future__ import annotations

import posixpath
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path

from citylod._version import __version__
from citylod.core.errors import InputError, UnsafePathError
from citylod.io.tiles3d.archive3tz import MAX_ENTRY_BYTES

__all__ = ["Remote", "is_url", "unfold_url"]

TIMEOUT_S = 30.0
_CHUNK = 1 << 20


def is_url(source: object) -> bool:
    """Whether ``source`` is an http(s) URL, also after ``pathlib.Path`` folded its ``//`` into ``/``."""
    return str(source).startswith(("http://", "https://", "http:/", "https:/"))


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

    def __init__(self, url: str, timeout_s: float | None = None) -> None:
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
        self.scheme, self.netloc = parts.scheme, parts.netloc
        self.origin = f"{parts.scheme}://{parts.netloc}"
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
        """The file's bytes; :class:`InputError` naming the URL when the server does not give them."""
        url = self.url_of(name)
        request = urllib.request.Request(url, headers={"User-Agent": f"citylod/{__version__}",
                                                       "Accept-Encoding": "identity"})
        try:
            with self._opener().open(request, timeout=self.timeout_s) as response:
                length = response.headers.get("Content-Length")
                if length is not None and length.isdigit() and int(length) > MAX_ENTRY_BYTES:
                    raise InputError(f"the server announces {int(length):,} bytes (more than "
                                     f"{MAX_ENTRY_BYTES:,}); refused", url)
                chunks, total = [], 0
                while chunk := response.read(_CHUNK):
                    total += len(chunk)
                    if total > MAX_ENTRY_BYTES:
                        raise InputError(f"more than {MAX_ENTRY_BYTES:,} bytes; refused", url)
                    chunks.append(chunk)
                return b"".join(chunks)
        except urllib.error.HTTPError as exc:
            raise InputError(f"HTTP {exc.code} {exc.reason}", url) from exc
        except urllib.error.URLError as exc:
            raise InputError(f"cannot reach the server ({exc.reason})", url) from exc
        except (TimeoutError, OSError) as exc:  # a read that stalls past the time-out, a reset connection
            raise InputError(f"no answer within {self.timeout_s:g} s ({exc})", url) from exc

    def size(self, name: str) -> int:
        """0: a remote file's size is known once it is read (no HEAD request per tile)."""
        return 0

    def _opener(self) -> urllib.request.OpenerDirector:
        origin = self.origin

        class _SameServer(urllib.request.HTTPRedirectHandler):
            """Follows a redirect only on the tileset's server (a renamed file, a trailing slash)."""

            def redirect_request(self, req, fp, code, msg, headers, newurl):  # type: ignore[no-untyped-def]
                parts = urllib.parse.urlsplit(urllib.parse.urljoin(req.full_url, newurl))
                if f"{parts.scheme}://{parts.netloc}" != origin:
                    raise InputError(f"the server redirects to {newurl}, another server than the tileset's",
                                     req.full_url)
                return super().redirect_request(req, fp, code, msg, headers, newurl)

        return urllib.request.build_opener(_SameServer)
