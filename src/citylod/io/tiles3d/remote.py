"""Tilesets served over HTTP(S), read file by file as a 3D Tiles client reads them.

``open_tileset("https://host/data/tileset.json")`` reads the tileset JSON, then each tile's content when a view
needs it, with one GET per file (urllib; HTTP keep-alive is not needed at these request rates). The tileset's
folder on the server stands where a local folder would: content URIs are resolved against it and must stay
inside it, as for files (:func:`citylod.io.tiles3d.tileset.safe_resolve`), so a tileset cannot make citylod
fetch from another host or path. The tileset URL's query string (an access token, a version) is sent with every
request, as CesiumJS's resources pass their query parameters on to derived ones.

Every request has a time-out and a size cap; an HTTP error, a refused connection or a time-out is one
:class:`~citylod.core.errors.InputError` naming the URL. Nothing is cached on disk: the renderer's memory cache
keeps what a view uses.
"""

from __future__ import annotations

import posixpath
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path, PurePosixPath

from citylod._version import __version__
from citylod.core.errors import InputError
from citylod.io.tiles3d.package import MAX_ENTRY_BYTES, is_url, unfold_url

__all__ = ["Remote", "is_url"]

TIMEOUT_S = 30.0
_CHUNK = 1 << 20


class Remote:
    """One tileset's folder on an HTTP(S) server; :meth:`read` fetches a file by its path inside that folder.

    ``root`` is a local stand-in path for the folder (nothing is written there): the tileset's files get paths
    below it, so the reader's path checks work unchanged.
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
        self.folder_url = urllib.parse.urlunsplit((parts.scheme, parts.netloc, posixpath.dirname(path) + "/", "", ""))
        self.entry = posixpath.basename(path)
        self.query = parts.query
        self.timeout_s = TIMEOUT_S if timeout_s is None else timeout_s
        host = parts.netloc.replace(":", "_")
        self.root = Path("/citylod-remote") / parts.scheme / host / PurePosixPath(posixpath.dirname(path)).relative_to("/")

    def url_of(self, name: str) -> str:
        """The URL of the file ``name`` (a relative POSIX path inside the folder)."""
        quoted = urllib.parse.quote(name, safe="/")
        return self.folder_url + quoted + (f"?{self.query}" if self.query else "")

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
        folder = self.folder_url

        class _StayInside(urllib.request.HTTPRedirectHandler):
            """Follows a redirect only within the tileset's folder (a renamed file, a trailing slash)."""

            def redirect_request(self, req, fp, code, msg, headers, newurl):  # type: ignore[no-untyped-def]
                parts = urllib.parse.urlsplit(newurl)
                if not urllib.parse.urlunsplit((parts.scheme, parts.netloc, parts.path, "", "")).startswith(folder):
                    raise InputError(f"the server redirects to {newurl}, outside the tileset's folder", req.full_url)
                return super().redirect_request(req, fp, code, msg, headers, newurl)

        return urllib.request.build_opener(_StayInside)
