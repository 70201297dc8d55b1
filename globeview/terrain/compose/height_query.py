"""Point height queries on the composed terrain (issue #16): what `globeview height`, the
status bar and the agreement tests read.

For each point the answer is the surface the LOD converges to: the composed tile at the
stack's finest level (`TerrainStack.heights`, so whatever the stack does at layer borders is
answered too), interpolated bilinearly between its nodes exactly as the mesh's triangles
span them. Heights stored in the tiles are ellipsoidal (h, metres above WGS84); the geoid
undulation N (EGM96, metres) gives the orthometric height H = h - N.

Which layer "answered" a point is the topmost visible layer whose own finest tile has data at
all four nodes around the point. Where no layer has all four nodes but one has some (the grid
cells just past its data's edge, where its surface ramps down to the ellipsoid), the answer
names that layer's edge and the weight its nodes have in the height there. In a layer's
border band, where it feathers into the layer below, the answer names both and the weight of
the upper one. None means no layer has a node around the point: the surface there is the
bare ellipsoid (h = 0), there is no terrain, and the answer has no heights (None), only the
undulation N (-N would read as an elevation "a.s.l." of the ellipsoid).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from globeview.errors import GlobeviewError
from globeview.terrain.compose.stack import TerrainStack
from globeview.terrain.dem.vdatum import egm96
from globeview.terrain.interpolate import bilinear
from globeview.terrain.quadtree import key_for_lonlat, tile_bounds_arrays

if TYPE_CHECKING:
    from globeview.terrain.store.tile_store import TileStore

#: What the `layer` field says where no layer has data.
NO_LAYER = "none (ellipsoid)"


@dataclass(frozen=True)
class HeightAnswer:
    """One point's heights. lon/lat degrees (WGS84); heights metres.

    ellipsoidal: h above the WGS84 ellipsoid (what the mesh holds); None where no layer has
        terrain (`NO_LAYER`);
    undulation: N, the EGM96 geoid above the ellipsoid there;
    orthometric: H = h - N (above the geoid, "a.s.l."); None where no layer has terrain;
    layer: the name of the layer that answered, or `NO_LAYER`;
    level: the quadtree level whose tile nodes were interpolated.
    """

    lon: float
    lat: float
    ellipsoidal: float | None
    undulation: float
    orthometric: float | None
    layer: str
    level: int

    @property
    def has_terrain(self) -> bool:
        """Whether a layer answered (else there are no heights, only N)."""
        return self.layer != NO_LAYER

    def to_dict(self) -> dict:
        return {
            "lon": self.lon,
            "lat": self.lat,
            "ellipsoidal_m": self.ellipsoidal,
            "geoid_undulation_m": self.undulation,
            "orthometric_m": self.orthometric,
            "layer": self.layer,
            "level": self.level,
        }


def check_lonlat(lon: np.ndarray, lat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Validated float64 copies (longitude wrapped into [-180, 180)); a `GlobeviewError`
    naming the first bad point otherwise (NaN, infinite, |lat| > 90)."""
    lon = np.atleast_1d(np.asarray(lon, dtype=np.float64))
    lat = np.atleast_1d(np.asarray(lat, dtype=np.float64))
    if lon.shape != lat.shape:
        raise GlobeviewError(f"{lon.size} longitudes but {lat.size} latitudes")
    bad = ~(np.isfinite(lon) & np.isfinite(lat))
    bad |= np.abs(np.where(np.isfinite(lat), lat, 0.0)) > 90.0
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise GlobeviewError(
            f"point {lon[i]:g},{lat[i]:g}: longitude must be finite and latitude in -90..90"
        )
    # 180 stays the east edge (key_for_lonlat maps it to the last column); beyond, wrap.
    wrapped = np.where(np.abs(lon) <= 180.0, lon, (lon + 180.0) % 360.0 - 180.0)
    return wrapped, lat


def _node_positions(
    level: int, kx: np.ndarray, ky: np.ndarray, lon: np.ndarray, lat: np.ndarray, size: int
) -> tuple[np.ndarray, np.ndarray]:
    """Fractional (row, col) node positions of the points inside their tiles."""
    w, s, e, n = tile_bounds_arrays(level, kx, ky)
    cols = (lon - w) / (e - w) * (size - 1)
    rows = (n - lat) / (n - s) * (size - 1)
    return rows, cols


def _by_tile(kx: np.ndarray, ky: np.ndarray) -> Iterator[tuple[int, int, np.ndarray]]:
    """(x, y, indices) of each distinct tile among the points' keys."""
    pairs = np.stack([kx, ky], axis=1)
    uniq, inverse = np.unique(pairs, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    for u, (x, y) in enumerate(uniq):
        yield int(x), int(y), np.flatnonzero(inverse == u)


def composed_heights(
    stack: TerrainStack, lon: np.ndarray, lat: np.ndarray, level: int | None = None
) -> np.ndarray:
    """Ellipsoidal heights (m) of the composed surface at the points: the tile at ``level``
    (default: the finest any visible layer has) bilinear between its nodes. One tile read per
    distinct tile, vectorised over the points in it."""
    lon, lat = check_lonlat(lon, lat)
    level = stack.max_level if level is None else int(level)
    kx, ky = key_for_lonlat(level, lon, lat)
    size = stack.tile_size
    rows, cols = _node_positions(level, kx, ky, lon, lat, size)
    out = np.zeros(lon.shape, dtype=np.float64)
    for x, y, idx in _by_tile(kx, ky):
        grid = stack.heights((level, x, y))
        out[idx] = bilinear(grid, rows[idx], cols[idx])
    return out


def answering_layers(stack: TerrainStack, lon: np.ndarray, lat: np.ndarray) -> list[str]:
    """Per point, the name of the topmost visible layer whose finest tile has data at the four
    nodes around the point (`NO_LAYER` where none does). Inside that layer's border band, where
    it feathers into a layer below (`globeview.terrain.compose.blend`), the answer names both
    and the upper layer's weight: ``"top over base (blend 0.42)"``. Where no layer has the four
    nodes but one has some, the surface is its data edge ramping down to the ellipsoid: the answer
    names it and the weight of its nodes there, ``"top over none (ellipsoid) (edge 0.37)"``."""
    lon, lat = check_lonlat(lon, lat)
    layers = stack.visible_layers
    index = _answering_index(layers, lon, lat)
    names = np.array([NO_LAYER if i < 0 else layers[i].name for i in index], dtype=object)
    _name_edges(names, layers, lon, lat, np.flatnonzero(index < 0))
    for i in np.unique(index[index > 0]):
        at = np.flatnonzero(index == i)
        w = stack.blend_weight(int(i), lon[at], lat[at])
        band = at[w < 1.0 - 5e-3]
        if band.size == 0:
            continue
        below = _answering_index(layers[:i], lon[band], lat[band])
        for p, b, wp in zip(band, below, w[w < 1.0 - 5e-3], strict=True):
            if b >= 0:
                names[p] = f"{layers[i].name} over {layers[b].name} (blend {wp:.2f})"
    return list(names)


def _answering_index(layers: list, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
    """Per point, the index in ``layers`` of the topmost one whose finest tile has data at the
    four nodes around the point (-1 where none does)."""
    index = np.full(lon.shape, -1, dtype=np.int64)
    open_ = np.ones(lon.shape, dtype=bool)
    for i in range(len(layers) - 1, -1, -1):
        if not open_.any():
            break
        st = layers[i].store
        lm = st.max_level
        todo = np.flatnonzero(open_)
        kx, ky = key_for_lonlat(lm, lon[todo], lat[todo])
        has = st.has_data(lm, kx, ky)
        rows, cols = _node_positions(lm, kx, ky, lon[todo], lat[todo], st.tile_size)
        for x, y, sub in _by_tile(kx[has], ky[has]):
            pos = np.flatnonzero(has)[sub]
            valid = _all_corners_valid(st.heights((lm, x, y)), rows[pos], cols[pos])
            hit = todo[pos[valid]]
            index[hit] = i
            open_[hit] = False
    return index


def _name_edges(
    names: np.ndarray, layers: list, lon: np.ndarray, lat: np.ndarray, points: np.ndarray
) -> None:
    """Name, in place, the ``points`` (indices) where the topmost layer with data at some of the
    four nodes of its finest tile around them has not all four: ``"X over none (ellipsoid)
    (edge w)"``, w the sum of the bilinear weights of its nodes with data (the share of its
    heights in the composed height when nothing lies below)."""
    open_ = points
    for layer in reversed(layers):
        if open_.size == 0:
            break
        weight = _data_weight(layer.store, lon[open_], lat[open_])
        hit = weight > 0.0
        for p, w in zip(open_[hit], weight[hit], strict=True):
            names[p] = f"{layer.name} over {NO_LAYER} (edge {w:.2f})"
        open_ = open_[~hit]


def _data_weight(st: TileStore, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
    """Per point, the sum of the bilinear weights of the nodes with data among the four around
    it in the store's finest tile (0 where the tile has no data)."""
    lm = st.max_level
    kx, ky = key_for_lonlat(lm, lon, lat)
    rows, cols = _node_positions(lm, kx, ky, lon, lat, st.tile_size)
    out = np.zeros(lon.shape, dtype=np.float64)
    has = st.has_data(lm, kx, ky)
    for x, y, sub in _by_tile(kx[has], ky[has]):
        at = np.flatnonzero(has)[sub]
        ok = np.isfinite(st.heights((lm, x, y))).astype(np.float64)
        out[at] = bilinear(ok, rows[at], cols[at])
    return out


def _all_corners_valid(grid: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Whether the (up to) four grid nodes around each fractional position are all data."""
    nr, nc = grid.shape
    r0 = np.clip(np.floor(rows).astype(np.int64), 0, nr - 2)
    c0 = np.clip(np.floor(cols).astype(np.int64), 0, nc - 2)
    ok = np.ones(rows.shape, dtype=bool)
    for dr in (0, 1):
        for dc in (0, 1):
            ok &= np.isfinite(grid[r0 + dr, c0 + dc])
    return ok


def geoid_undulation(lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
    """EGM96 undulation N (m, geoid above the WGS84 ellipsoid) at the points, from the geoid
    grid shipped with the package (`globeview.terrain.dem.vdatum.egm96`)."""
    return np.asarray(egm96().undulation(lon, lat), dtype=np.float64).reshape(np.shape(lon))


def query_heights(stack: TerrainStack, lon: np.ndarray, lat: np.ndarray) -> list[HeightAnswer]:
    """h, N, H = h - N and the answering layer at each point (see the module docstring); no
    h and H (None) where no layer answered."""
    lon, lat = check_lonlat(lon, lat)
    level = stack.max_level
    h = composed_heights(stack, lon, lat, level)
    n = geoid_undulation(lon, lat)
    names = answering_layers(stack, lon, lat)
    answers = []
    for i in range(lon.size):
        terrain = names[i] != NO_LAYER
        answers.append(
            HeightAnswer(
                float(lon[i]),
                float(lat[i]),
                float(h[i]) if terrain else None,
                float(n[i]),
                float(h[i] - n[i]) if terrain else None,
                str(names[i]),
                level,
            )
        )
    return answers
