"""Store generations: an update commits beside the files readers have open, then collects
garbage (issue #25 item 5, design 2.8 "Atomicity, generations, GC").

A store's manifest says which *generation* it is (0 for a first build and for every format-7
store written before generations). Every file a reader reads by name is content-addressed
(chunks ``chunks/LL/<cy>/<cx>-<h16>.tif``, shards ``meta/...-<h16>.gvm``: `layout`), so an
update to generation g + 1 (`commit_generation`, under the store folder's flock, `store_lock`):

1. moves its new content-named files into the live store beside generation g's (a name that
   is already there holds the same bytes: it is kept), each fsynced, by rename(2) (never a
   half-written file under a store name);
2. renames its whole facts folder into place as ``generations/facts-<g+1>/facts/`` (the
   build facts only the next update reads: one rename, so a killed update never leaves one
   generation's manifest with another's facts);
3. writes ``generations/manifest-<g+1>.json`` (fsync, rename), and ``manifest-<g>.json`` when
   the store has none yet;
4. replaces ``manifest.json`` (fsync, `os.replace`, fsync of the folder): the switch (a failure
   before it takes back what was moved in); then the level VRTs (``level_LL.vrt``: stable
   names for GDAL users, each replaced atomically; a reader or a store killed in between
   has the previous generation's, which `TileStore` accepts);
5. deletes every store file that neither generation g + 1 nor g references (and temporary
   leftovers of killed writes): `collect_garbage`. It also runs before step 1, keeping g and
   g - 1, so what a killed update left is gone before the next one writes.

A reader that opened generation g (the window's `TileStore`, an HTTP client) goes on reading
g's files, all still there, and never a mix: it knows its chunks and shards by their content
names. Two updates later they are collected: its next read of a file it has not opened yet is
one line, "... the store was updated; reopen it" (`local.LocalFiles`, `http.RemoteSource`).

Departures from the design, for what main has: updates still build in the hidden building
folder (hard links of the kept chunks, as `ingest.update` does) and *move* the new files in at
commit, rather than writing into the live store: a refused or failed update then never
touches the store, and the build's code is unchanged. The facts are per generation folders
(the design's shard-recorded facts sha256 would change the shard format).
"""

from __future__ import annotations

import contextlib
import io
import logging
import os
import shutil
import uuid
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX: updates are not serialised
    fcntl = None  # type: ignore[assignment]

from globeview.errors import StoreError
from globeview.terrain.store.identify import MANIFEST_NAME, is_store_file, store_files
from globeview.terrain.store.layout import (
    STORE_DIRS,
    facts_root,
    generation_manifest_name,
    is_store_path,
    level_vrt_name,
)
from globeview.terrain.store.local import LocalFiles
from globeview.terrain.store.metadata import StoreMetadata
from globeview.terrain.store.schema import ManifestError, StoreManifest

__all__ = [
    "collect_garbage",
    "commit_generation",
    "read_generation",
    "referenced_files",
    "remove_empty_dirs",
    "store_lock",
    "write_durable",
]

log = logging.getLogger("globeview.terrain.store")


def _fsync_dir(folder: Path) -> None:
    """Make a folder's entries (a rename into it) durable; a no-op where folders cannot be
    opened (not POSIX)."""
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _fsync_file(path: Path) -> None:
    with path.open("rb") as f:
        os.fsync(f.fileno())


def write_durable(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path``: a temporary name in its folder, fsync, `os.replace`, fsync
    of the folder. A reader sees the old bytes or the new, never a part; after a crash the
    file is one or the other."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.name}.tmp-{uuid.uuid4().hex[:12]}")
    try:
        with tmp.open("xb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _fsync_dir(path.parent)


@contextlib.contextmanager
def store_lock(folder: Path) -> Iterator[None]:
    """Hold the store's flock for the block: one commit or garbage collection at a time,
    whatever process runs it. The lock is the store folder's own (flock on a folder: no lock
    file, so a failed update leaves the store as it was, byte for byte); the kernel drops it
    when its holder dies (kill -9 included)."""
    if fcntl is None:  # pragma: no cover - not POSIX: commits are not serialised
        yield
        return
    fd = os.open(folder, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # closing drops the flock


def read_generation(folder: Path, generation: int) -> StoreManifest | None:
    """The manifest of generation ``generation`` from ``generations/manifest-<g>.json``;
    None when it is not there or not a sound manifest."""
    return _parse(folder / generation_manifest_name(generation))


def _parse(path: Path) -> StoreManifest | None:
    import json

    try:
        return StoreManifest.from_json(json.loads(path.read_bytes().decode("utf-8")))
    except (OSError, UnicodeDecodeError, ValueError, ManifestError, RecursionError):
        return None


def manifest_bytes(manifest: StoreManifest) -> bytes:
    """The manifest as its file holds it (compact JSON)."""
    f = io.StringIO()
    manifest.write(f)
    return f.getvalue().encode("utf-8")


def referenced_files(folder: Path, manifest: StoreManifest) -> set[str]:
    """The files (relative, '/'-separated) a generation's readers read by name: its shards
    (the tree walked from the top) and its chunk files. StoreError (one line) when a shard
    is missing or damaged: then nobody may conclude what is garbage."""
    files = LocalFiles(folder)
    names: set[str] = set()

    def load(name: str, sha256: str, size: int) -> bytes:
        names.add(name)
        return files.read_small(name, sha256, size)

    meta = StoreMetadata(manifest, load, files.describe)
    for _lv, _cy, _cx, facts in meta.iter_chunks():
        if facts.file is not None:
            names.add(facts.file)
    return names


def _kept(folder: Path, keep: Sequence[StoreManifest]) -> tuple[set[str], tuple[str, ...]]:
    """(names, folder prefixes) of what generations ``keep`` (the current one first) need."""
    names = {MANIFEST_NAME}
    prefixes: list[str] = []
    for m in keep:
        names |= referenced_files(folder, m)
        names.add(generation_manifest_name(m.generation))
        prefixes.append(facts_root(m.generation) + "facts/")
    current = keep[0]
    for lv in range(current.max_level + 1):  # stable names: the current generation's levels
        names |= {level_vrt_name(lv), level_vrt_name(lv) + ".aux.xml"}
    return names, tuple(prefixes)


def collect_garbage(folder: Path, keep: Sequence[StoreManifest | None]) -> list[str]:
    """Delete the store files no generation in ``keep`` references (the current one first:
    only its levels keep their VRTs) and temporary leftovers of killed writes; returns what
    was removed (relative names). The caller holds `store_lock`. Only files globeview writes
    are ever looked at (`identify.store_files`): a user's file stays. When a kept
    generation's shard tree cannot be read, nothing is deleted (StoreError)."""
    gens = [m for m in keep if m is not None]
    if not gens:
        return []
    names, prefixes = _kept(folder, gens)
    removed: list[str] = []
    for p in store_files(folder):
        rel = p.relative_to(folder).as_posix()
        tmp = ".tmp-" in rel or rel.endswith(".part")
        if not tmp and (rel in names or rel.startswith(prefixes)):
            continue
        with contextlib.suppress(FileNotFoundError):
            p.unlink()
            removed.append(rel)
    remove_empty_dirs(folder)
    return removed


def remove_empty_dirs(folder: Path) -> None:
    """Remove the empty folders of the store's folders (`STORE_DIRS`), deepest first (an old
    generation's ``facts/`` too); a folder still holding something (not ours) stays."""
    for name in STORE_DIRS:
        top = folder / name
        if not top.is_dir() or top.is_symlink():
            continue
        for sub, _dirs, _files in sorted(os.walk(top), key=lambda t: -len(t[0])):
            with contextlib.suppress(OSError):
                os.rmdir(sub)


def _gc(folder: Path, keep: Sequence[StoreManifest | None]) -> None:
    """`collect_garbage`, a failure of which never fails the update (the garbage stays)."""
    try:
        removed = collect_garbage(folder, keep)
    except (StoreError, OSError) as exc:
        log.warning("%s: garbage of older generations kept (%s)", folder, exc)
        return
    if removed:
        log.info("%s: %d files of older generations removed", folder, len(removed))


def _content_files(building: Path) -> Iterator[tuple[Path, str]]:
    """The files of a building folder that go into the store by name as they are (chunks,
    shards; not the manifest, the level VRTs or the facts, which `commit_generation` places
    itself)."""
    for sub, _dirs, files in os.walk(building):
        for n in sorted(files):
            p = Path(sub) / n
            rel = p.relative_to(building).as_posix()
            if rel.startswith("facts/") or ("/" not in rel and not rel.startswith("sources-")):
                continue  # the facts folder; manifest.json and level_LL.vrt at the top
            if is_store_path(rel):
                yield p, rel


def _move_in(building: Path, out: Path) -> int:
    """Move the new content-named files of ``building`` into ``out`` (fsynced, then renamed:
    never half-written under their names); a name already in ``out`` holds the same bytes
    (hard-linked from it, or rebuilt identically) and is left as it is. Returns how many
    were moved."""
    folders: set[Path] = set()
    moved = 0
    for src, rel in _content_files(building):
        dst = out / rel
        if os.path.lexists(dst):
            continue
        _fsync_file(src)
        dst.parent.mkdir(parents=True, exist_ok=True)
        os.rename(src, dst)
        folders.add(dst.parent)
        moved += 1
    for d in folders:
        _fsync_dir(d)
    return moved


def _move_facts(building: Path, out: Path, generation: int) -> None:
    """Rename the building folder's whole ``facts/`` folder to generation ``generation``'s
    (one rename: the next update reads one generation's facts, never a mix)."""
    src = building / "facts"
    if not src.is_dir():
        return
    for sub, _dirs, files in os.walk(src):
        for n in files:
            _fsync_file(Path(sub) / n)
    dst = out / facts_root(generation) / "facts"
    if dst.parent.exists():  # left by a killed commit of the same generation: ours alone
        shutil.rmtree(dst.parent)
    dst.parent.mkdir(parents=True)
    os.rename(src, dst)
    _fsync_dir(dst.parent)


def commit_generation(
    building: Path,
    out: Path,
    old: StoreManifest,
    new: StoreManifest,
    fault: Callable[[str], None] = lambda _point: None,
) -> None:
    """Commit the store built in ``building`` as generation ``new.generation`` (= the live
    store's ``old.generation`` + 1) of the store ``out``, beside generation ``old``'s files
    (steps in the module's docstring). A failure before the switch takes back what this
    commit moved in (the store as it was); after it, only the garbage stays. ``fault(point)``
    is the ingest's fault injection: "generation-files" (= "commit") with the new files in,
    "generation-switch" just before the switch, "generation-vrts" just after it."""
    if new.generation != old.generation + 1:
        raise ValueError("a new generation follows the store's")
    with store_lock(out):
        live = _parse(out / MANIFEST_NAME)
        if live is None or (live.generation, live.shards.top) != (old.generation, old.shards.top):
            raise StoreError(f"{out} was changed by another ingest during this one; run it again")
        previous = read_generation(out, old.generation - 1) if old.generation else None
        _gc(out, [old, previous])  # what a killed update left
        data = manifest_bytes(new)
        try:
            _move_in(building, out)
            _move_facts(building, out, new.generation)
            write_durable(out / generation_manifest_name(new.generation), data)
            fault("generation-files")
            fault("commit")
            here = out / generation_manifest_name(old.generation)
            if not here.exists():  # a store of before generations, or of a first build
                write_durable(here, (out / MANIFEST_NAME).read_bytes())
            fault("generation-switch")
            write_durable(out / MANIFEST_NAME, data)
        except BaseException:
            now = _parse(out / MANIFEST_NAME)
            if now is None or now.generation != new.generation:  # (not switched after all)
                _gc(out, [old, previous])  # take back what was moved in (a kill leaves it)
            raise
        fault("generation-vrts")
        # The level VRTs (stable names, for GDAL) after the switch: a reader that opened the
        # new manifest a moment before them, or a store killed here, has the previous
        # generation's, which `TileStore` accepts (its tiles never read through them).
        for vrt in sorted(building.glob("level_*.vrt")):
            if is_store_file(vrt.name):
                _fsync_file(vrt)
                os.replace(vrt, out / vrt.name)
        _fsync_dir(out)
        _gc(out, [new, old])
