"""What the user typed to open terrain: a local path (a DEM file or a tile store folder) or
the URL of a store served over HTTP, told apart and checked in one place for the command line
(`globeview render/info URL`) and the window (File > Open URL...).

Only ``http://`` and ``https://`` URLs are stores read remotely (`TileStore.open` reads them
with range requests, `globeview.terrain.store.http`); any other ``scheme://`` text (``file://``,
``ftp://``, ``s3://``...) is refused in one line that says what to type instead, rather than
being taken for a file name. Spaces in the path are percent-encoded (what a browser sends for
a folder named ``my store``); whitespace or other characters that cannot be in a host are
refused. Reachability, the manifest and its size are the remote reader's checks (one
`StoreError` line each).
"""

from __future__ import annotations

import re
import urllib.parse

from globeview.errors import GlobeviewError

__all__ = ["MAX_URL_CHARS", "check_store_url", "is_store_url", "open_store_url", "url_scheme"]

#: Longest URL accepted (browsers and servers commonly stop near 8 kB).
MAX_URL_CHARS = 4096

_SCHEME = re.compile(r"^\s*([A-Za-z][A-Za-z0-9+.-]*)://")
_REMOTE_SCHEMES = ("http", "https")
#: Host names, IPv4 and IPv6 literals (as `urlsplit`'s hostname: no brackets, no whitespace).
_HOST = re.compile(r"^([0-9a-f:.]+|[a-z0-9_][a-z0-9_.-]*)$")


def url_scheme(text: str) -> str | None:
    """The lower-case scheme of ``text`` when it starts like a URL (``name://``), else None
    (a path, even ``C:\\x`` or ``./http:/x``)."""
    m = _SCHEME.match(str(text))
    return m.group(1).lower() if m else None


def is_store_url(text: str) -> bool:
    """Whether ``text`` is meant as a URL (any ``scheme://``), to be checked with
    `check_store_url` rather than opened as a path."""
    return url_scheme(text) is not None


def check_store_url(text: str) -> str:
    """The URL of a remote store as it will be requested: stripped, spaces in the path
    percent-encoded, a trailing slash dropped. Raises a one-line `GlobeviewError` for
    another scheme, no host, a bad port, user info, or a URL over `MAX_URL_CHARS`."""
    raw = str(text).strip()
    shown = raw if len(raw) <= 80 else raw[:77] + "..."
    scheme = url_scheme(raw)
    if scheme is None:
        raise GlobeviewError(f"not a URL: {shown!r} (a store URL starts with https://)")
    if scheme not in _REMOTE_SCHEMES:
        hint = (
            "; open a local store by its folder path instead"
            if scheme == "file"
            else "; serve the store over HTTP, as any static web server does"
        )
        raise GlobeviewError(
            f"{scheme}:// URLs are not supported (stores are read over http:// or https://){hint}"
        )
    if len(raw) > MAX_URL_CHARS:
        raise GlobeviewError(f"URL too long ({len(raw)} characters, at most {MAX_URL_CHARS})")
    if any(c in raw for c in "\r\n\t\0"):
        raise GlobeviewError(f"URL {shown!r} holds control characters")
    parts = urllib.parse.urlsplit(raw)
    try:
        port = parts.port  # ValueError: not a number or out of 0..65535
    except ValueError:
        raise GlobeviewError(f"URL {shown!r} has a bad port") from None
    if port == 0:
        raise GlobeviewError(f"URL {shown!r} has a bad port")
    if "@" in parts.netloc:
        raise GlobeviewError(f"URL {shown!r}: user names and passwords in URLs are not supported")
    host = parts.hostname or ""  # lower case, IPv6 brackets stripped
    if not _HOST.match(host):
        raise GlobeviewError(f"URL {shown!r} has no valid host name")
    if parts.query or parts.fragment:
        raise GlobeviewError(
            f"URL {shown!r}: a store URL names the store's folder (no ?query or #fragment)"
        )
    # Spaces and other characters a server needs encoded, once (an already encoded %20 stays).
    path = urllib.parse.quote(parts.path, safe="/%:@!$&'()*+,;=~-._")
    return urllib.parse.urlunsplit((scheme, parts.netloc, path.rstrip("/"), "", ""))


def open_store_url(text: str):
    """The `TileStore` of a store URL (checked with `check_store_url`, then opened over HTTP
    by `TileStore.open`: reads the manifest only). One-line `GlobeviewError` (`StoreError`)
    for a bad URL, an unreachable server or a folder that is not a store."""
    from globeview.terrain.store.tile_store import TileStore

    return TileStore.open(check_store_url(text))
