"""`globeview info`: describe DEM rasters (bounds, resolution, nodata, value range) and tile
stores, local folders or URLs of stores served over HTTP (levels, chunks, sources; of a URL
only the manifest is read, a folder's files are checked against it first)."""

from __future__ import annotations

import argparse

from globeview.cli.dem_options import add_dem_options


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register `info`'s arguments on its subparser."""
    parser.add_argument(
        "dems",
        nargs="*",
        metavar="DEM|STORE|URL",
        help="raster files GDAL can read, tile store folders or store URLs "
        "(https://HOST/path/store) (default: the embedded DEMs)",
    )
    add_dem_options(parser)
    parser.add_argument("--json", action="store_true", help="print a JSON list instead of text")
    parser.add_argument(
        "--embedded", action="store_true", help="describe the DEMs shipped in data/"
    )
    parser.add_argument(
        "--verify",
        action="store_true",
        help="check every chunk file of a store against its sha256 (reads all data; "
        "without it, only their sizes are checked)",
    )


def run(args: argparse.Namespace) -> int:
    """Print a summary (or JSON) per DEM. DemError propagates to the CLI's one-line handler."""
    import json

    from globeview.terrain.dem.data import embedded_dem_paths
    from globeview.terrain.dem.reader import open_dem
    from globeview.terrain.sources import source_kind

    paths = [*args.dems]
    if args.embedded or not paths:
        paths = [*map(str, embedded_dem_paths()), *paths]
    infos = []
    for p in paths:
        if source_kind(p) == "store":  # (a URL no backend reads, a plain folder: one line)
            infos.append(store_info(p, full=args.verify))
            continue
        with open_dem(p, crs=args.crs, vdatum=args.vdatum) as dem:
            infos.append(dem.info)
    if args.json:
        print(json.dumps([i.to_dict() for i in infos], indent=2))
    else:
        print("\n\n".join(i.summary() for i in infos))
    return 0


class StoreInfo:
    """What `globeview info` says about a tile store (from its manifest alone)."""

    def __init__(self, where: str, store, checked: int | None = None) -> None:
        m = store.manifest
        self.where = where
        self.format_version = m.header.format_version
        self.generation = int(m.generation)
        self.created_by = m.header.created_by
        self.tile_n = store.tile_n
        self.max_level = store.max_level
        self.wavelet = m.wavelet
        self.bounds = tuple(float(v) for v in store.bounds)
        self.sources = [
            {"path": s.path, "crs": s.crs, "vertical_datum": s.vertical_datum} for s in m.sources
        ]
        self.checked = checked
        self.shards = int(m.shards.count)
        self.levels = []
        for lv in m.levels:
            self.levels.append(
                {
                    "level": int(lv.level),
                    "file": lv.file,
                    "chunk_files": int(lv.chunks),
                    "tiles": int(lv.tiles),
                    "bytes": int(lv.bytes),
                    "node_spacing_deg": float(lv.node_spacing_deg),
                    "max_error_m": None if lv.level_error is None else float(lv.level_error),
                }
            )

    def to_dict(self) -> dict[str, object]:
        return {
            "store": self.where,
            "format_version": self.format_version,
            "generation": self.generation,
            "created_by": self.created_by,
            "tile_n": self.tile_n,
            "max_level": self.max_level,
            "wavelet": self.wavelet,
            "bounds": list(self.bounds),
            "sources": self.sources,
            "levels": self.levels,
            "shards": self.shards,
            "chunk_files_checked": self.checked,
        }

    def _updates(self) -> str:
        """How the generation came to be, for people."""
        if self.generation == 0:
            return "as first built"
        return "1 update" if self.generation == 1 else f"{self.generation} updates"

    def summary(self) -> str:
        w, s, e, n = self.bounds
        chunks = [lv["chunk_files"] for lv in self.levels if lv["chunk_files"] is not None]
        finest = self.levels[-1] if self.levels else None
        lines = [
            f"{self.where}",
            f"  tile store, format {self.format_version} ({self.created_by}), generation "
            f"{self.generation} ({self._updates()})",
            f"  levels 0..{self.max_level}, tiles of {(1 << self.tile_n) + 1} samples a side, "
            f"wavelet {self.wavelet}",
            f"  bounds: {w:.6f}..{e:.6f} E, {s:.6f}..{n:.6f} N",
        ]
        if chunks:
            size = sum(int(lv["bytes"]) for lv in self.levels)
            lines.append(
                f"  chunk files: {sum(chunks)} over {len(chunks)} levels ({size / 1e6:.1f} MB), "
                f"metadata shards: {self.shards}"
            )
        if finest is not None:
            lines.append(
                f"  finest level {finest['level']}: node spacing "
                f"{finest['node_spacing_deg'] * 3600:.3f} arc-seconds"
            )
        for src in self.sources:
            lines.append(f"  source: {src['path']} ({src['crs']}, {src['vertical_datum']})")
        return "\n".join(lines)


def store_info(text: str, full: bool = False) -> StoreInfo:
    """Open a store (`open_source`) and describe it: a remote one from its manifest only; a
    local one after checking every chunk file's size against its shard record (``full``:
    its sha256 too, reading all data; `TileStore.verify`, a StoreError line naming the first
    damaged one)."""
    from globeview.terrain.sources import check_source, open_source

    where = check_source(text)  # a URL as it is requested
    store = open_source(where)
    try:
        checked = None
        if not store.is_remote or full:
            # Opening checks the manifest, the top shard and the level VRTs; a chunk truncated
            # or missing fails only when a tile is read, so every chunk's size is checked
            # (one stat each) and, with --verify, its sha256 (seconds a GB).
            checked = store.verify(full=full)
        return StoreInfo(where, store, checked)
    finally:
        store.close()
