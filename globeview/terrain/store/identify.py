"""What a path is, as far as stores go: a globeview store (of which format), somebody
else's folder, a file, nothing (`identify`), read from the manifest alone and never modifying
anything; the names of the files globeview writes in a store (`is_store_file`).

A store is recognised *positively*: its manifest carries ``"format": "globeview-tile-store"``
and a ``format_version``, which only globeview writes (stores of format 2, written before the
marker, are recognised by their manifest *and* holding only store files). Anything else with
a ``manifest.json`` is somebody else's folder: ingest never replaces it, `TileStore.open`
refuses it.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

from globeview.terrain.store.layout import STORE_DIRS, is_store_path
from globeview.terrain.store.schema import FORMAT_VERSION, STORE_FORMAT, StoreHeader

__all__ = [
    "MANIFEST_NAME",
    "StoreIdentity",
    "identify",
    "is_store_entry",
    "is_store_file",
    "read_manifest",
    "store_files",
]

MANIFEST_NAME = "manifest.json"

# Files globeview writes in a store (GDAL may add a .aux.xml next to a level).
# (Format 5: level_LL.vrt mosaics chunk files level_LL_rRRRR_cCCCC.tif; .npz sidecars hold
# per-chunk build facts; level_LL.tif is format 4's one file per level.)
# (Format 7: the folders `layout.STORE_DIRS` and sources-<h16>.json, see `layout`.)
_STORE_FILE = re.compile(
    r"^(manifest\.json(\.part|\.tmp-[0-9a-f]{12})?|sources-[0-9a-f]{16}\.json"
    r"|level_\d\d(_r\d{4,}_c\d{4,})?\.(tif|vrt|npz)(\.aux\.xml)?)$"
)


def is_store_file(name: str) -> bool:
    """Whether ``name`` is a file name globeview writes at the top of a store."""
    return bool(_STORE_FILE.match(name))


def is_store_entry(folder: Path, name: str) -> bool:
    """Whether entry ``name`` of a store folder is globeview's: a store file, or one of the
    folders of format 7 (`layout.STORE_DIRS`: not walked here, so `identify` stays one
    listing whatever the store's size; `store_files` walks them)."""
    if name in STORE_DIRS:
        p = folder / name
        return p.is_dir() and not p.is_symlink()
    return is_store_file(name)


def store_files(folder: Path) -> list[Path]:
    """Every file globeview wrote in a store folder, its subfolders walked (chunks, shards,
    facts): what removing a store removes. Nothing else is listed (a user's file stays)."""
    out: list[Path] = []
    for e in folder.iterdir():
        if e.name in STORE_DIRS and e.is_dir() and not e.is_symlink():
            for sub, _dirs, names in os.walk(e):
                for n in names:
                    p = Path(sub) / n
                    if is_store_path(p.relative_to(folder).as_posix()) or ".tmp-" in n:
                        out.append(p)
        elif is_store_file(e.name) and e.is_file():
            out.append(e)
    return out


class StoreIdentity:
    """What a path is, as far as stores go (see `identify`).

    kind: "absent" | "file" | "empty" (an empty folder) | "store" (a globeview store of
    ``version``, marker present) | "legacy" (a globeview store of format 2, written before
    the marker existed: recognised by its manifest *and* holding only store files) |
    "foreign" (anything else: never modified).
    """

    def __init__(self, kind: str, version: object = None, extra: str | None = None) -> None:
        self.kind = kind
        self.version = version
        self.extra = extra  # a file that is not a store file, when there is one

    @property
    def is_globeview(self) -> bool:
        return self.kind in ("store", "legacy")

    @property
    def is_current(self) -> bool:
        return self.kind == "store" and self.version == FORMAT_VERSION


def read_manifest(path: Path) -> dict[str, object] | None:
    """The parsed JSON object in ``path``'s manifest, unchecked (`StoreHeader.peek` reads
    its header; `StoreManifest.from_json` checks all of it), or None if it is missing,
    unreadable or not an object."""
    try:
        data = json.loads((path / MANIFEST_NAME).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError):
        return None
    return data if isinstance(data, dict) else None


def identify(path: str | Path) -> StoreIdentity:
    """Classify ``path`` without modifying anything (reads the manifest only)."""
    p = Path(path)
    if not p.exists() and not p.is_symlink():
        return StoreIdentity("absent")
    if p.is_symlink() or not p.is_dir():
        return StoreIdentity("file")
    try:
        names = sorted(e.name for e in p.iterdir())
    except OSError:
        return StoreIdentity("foreign")
    if not names:
        return StoreIdentity("empty")
    extra = next((n for n in names if not is_store_entry(p, n)), None)
    man = read_manifest(p)
    if man is None:
        return StoreIdentity("foreign", extra=extra)
    head = StoreHeader.peek(man)
    if head.format == STORE_FORMAT:
        return StoreIdentity("store", head.format_version, extra)
    created = head.created_by
    if (
        head.format_version == 2
        and isinstance(created, str)
        and created.startswith("globeview ")
        and extra is None
    ):
        return StoreIdentity("legacy", 2)
    return StoreIdentity("foreign", extra=extra)
