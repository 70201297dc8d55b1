"""`globeview.Globe`: the public Python API, a globe you build and render from a script or a
notebook, without a window.

A `Globe` wraps the application model (`globeview.model.Globe`: terrain, camera, overlays,
LOD provider, tool, display settings, evented) with the plugin registry and an overlay host,
and draws it headless through the one frame pipeline (`GlobeSession.render` into an EGL
offscreen target, as ``globeview render`` does). ``globeview.show(globe)`` opens the window
on the same model: a change made from either side is seen by the other.

Units and frames: longitudes and latitudes are geodetic degrees on WGS84 (longitude east,
latitude north), heights are metres above the WGS84 ellipsoid unless said otherwise (the
measured profile's ``height_m`` is orthometric, above the EGM96 geoid, as ``globeview
height`` prints it), headings are degrees clockwise from north and pitches degrees from the
horizontal (-90 looks straight down). Images are (height, width, 4) uint8 RGBA, row 0 at the
top.

Every error of the caller's input or environment is one `globeview.errors.GlobeviewError`
line (`DemError` for a DEM, `RenderError` when no headless OpenGL can be made), raised before
anything changed: a refused DEM, overlay or LOD provider leaves the globe as it was.
"""

from __future__ import annotations

import contextlib
import math
import os
import time
import weakref
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from globeview.app.dem_input import array_dem_file, checked_array_dem, is_data_array
from globeview.app.lod_host import check_lod_name
from globeview.app.overlay_host import OverlayHost
from globeview.errors import GlobeviewError
from globeview.model.camera import Camera, check_lonlat_hpr
from globeview.model.display import DisplaySettings
from globeview.model.globe import DEFAULT_LOD
from globeview.model.globe import Globe as GlobeModel
from globeview.plugins.api import PluginKind
from globeview.plugins.registry import PluginRegistry
from globeview.terrain.compose.height_query import query_heights
from globeview.terrain.compose.stack import TerrainLayer, TerrainStack

if TYPE_CHECKING:
    from globeview.app.session import GlobeSession

__all__ = ["CameraPose", "Globe", "Profile"]

#: Image sides (pixels) `Globe.render` accepts.
SIZE_RANGE_PX = (16, 16384)
#: The size `Globe.render` and `Globe.save` draw at when none is given (width, height).
DEFAULT_SIZE = (960, 540)
#: Where a new globe's camera is: 20 000 km above 0°E 20°N, looking down.
HOME = (0.0, 20.0, 2.0e7)


@dataclass(frozen=True)
class CameraPose:
    """Where the camera is and where it looks.

    Attributes:
        lon, lat: geodetic degrees (WGS84); lon in -180..180.
        height: metres above the WGS84 ellipsoid.
        heading: degrees clockwise from north, 0..360.
        pitch: degrees from the horizontal, -90 (straight down) .. 90.
        roll: degrees, turning the image clockwise.
    """

    lon: float
    lat: float
    height: float
    heading: float = 0.0
    pitch: float = -90.0
    roll: float = 0.0


@dataclass(frozen=True)
class Profile:
    """A measurement between A and B (`Globe.measure`), made by the ``measure`` tool.

    Attributes:
        a, b: (lon, lat) degrees.
        distance_m: geodesic length on WGS84 (Karney), metres.
        chord_m: straight (ECEF) distance between A and B at their terrain heights, metres.
        azimuth_deg: at A toward B; back_azimuth_deg: at B toward A (degrees clockwise from
            north, 0..360).
        s_m: (n,) distance of each sample from A along the geodesic, metres.
        lon, lat: (n,) the samples, degrees.
        height_m: (n,) orthometric terrain height there (metres above the EGM96 geoid; NaN
            where no terrain could be read).
        ellipsoidal_m: (n,) the same heights above the WGS84 ellipsoid, metres.
    """

    a: tuple[float, float]
    b: tuple[float, float]
    distance_m: float
    chord_m: float
    azimuth_deg: float
    back_azimuth_deg: float
    s_m: np.ndarray
    lon: np.ndarray
    lat: np.ndarray
    height_m: np.ndarray
    ellipsoidal_m: np.ndarray


class Globe:
    """A virtual globe you can render headless (EGL) and show in a window.

    Args:
        embedded: start with globeview's shipped DEMs (global ETOPO and the examples'
            DEMs; ingested into the cache on first use) and the country borders; default: an
            empty globe (the WGS84 ellipsoid) to add DEMs to.
        registry: the plugin registry (default: the installed plugins, with the settings
            ``globeview plugins`` stores; settings given here are not stored).
        lod: the LOD provider's name (default ``chunked-sse``).

    Example::

        import globeview
        globe = globeview.Globe()
        globe.add_dem("N44W072.hgt")
        globe.fly_to(-71.3, 44.27, 12_000, heading=20, pitch=-35)
        rgba = globe.render((800, 600))   # (600, 800, 4) uint8
        globe.save("white_mountains.png")
    """

    def __init__(
        self,
        *,
        embedded: bool = False,
        registry: PluginRegistry | None = None,
        lod: str = DEFAULT_LOD,
    ) -> None:
        if registry is None:
            registry = PluginRegistry().discover()
        self.registry = registry
        check_lod_name(registry, lod)
        terrain = _embedded_terrain() if embedded else TerrainStack()
        #: The application model (evented): the window shows this very object.
        self.model = GlobeModel(terrain, Camera.from_lonlat(*HOME), lod=lod)
        #: Opens overlay files onto the model through the installed layer types.
        self.overlay_host = OverlayHost(self.model, registry)
        self._gl: _Headless | None = None
        self._release: Callable[[], Any] = lambda: None
        self._size = DEFAULT_SIZE
        if embedded:
            self.overlay_host.open_embedded()

    # -- terrain ---------------------------------------------------------------------------
    @property
    def terrain(self) -> TerrainStack:
        """The DEM layers (bottom first), composed by priority: later ones on top."""
        return self.model.terrain

    @property
    def dems(self) -> list[str]:
        """The names of the DEM layers, bottom first."""
        return [ly.name for ly in self.terrain.layers]

    def add_dem(
        self,
        source: Any,
        *,
        transform: Any = None,
        crs: Any = None,
        nodata: float | None = None,
        name: str | None = None,
        vdatum: str | None = None,
    ) -> TerrainLayer:
        """Add a DEM on top of the others and return its layer.

        Args:
            source: a DEM file path (GeoTIFF, SRTM .hgt, anything GDAL reads), a tile store
                folder, a store URL (``https://...``), a numpy array of heights (metres;
                rows x columns, row 0 at the top) with ``transform`` and ``crs``, or an
                xarray ``DataArray`` whose CRS and transform rioxarray reads.
            transform: an array's pixel -> CRS `affine.Affine` (of pixel corners, as
                rasterio's), or its 6 numbers; overrides a DataArray's.
            crs: the array's horizontal CRS ('EPSG:4326', WKT, a pyproj or rasterio CRS);
                overrides a DataArray's. For a DEM file: its CRS when the file lacks one.
            nodata: the value of missing heights in an array (NaN always is).
            name: the layer's name (default: the file's, or "array").
            vdatum: what the heights are measured from: "egm96" (the geoid, as most DEMs)
                or "ellipsoid"; default: the file's own, EGM96 for an array.

        Files and arrays are ingested into the tile cache once (an unchanged one opens at
        once next time). Raises a one-line `DemError` / `StoreError` (a `GlobeviewError`)
        for a source that cannot be a DEM; the globe is then unchanged.
        """
        from globeview.terrain.sources import open_source

        if isinstance(source, (str, os.PathLike)):
            if transform is not None or nodata is not None:
                raise GlobeviewError("add_dem: transform= and nodata= are for arrays only")
            text = os.fspath(source)
            store = open_source(text, crs=None if crs is None else str(crs), vdatum=vdatum)
            default_name = Path(text.rstrip("/")).stem or "dem"
        elif isinstance(source, np.ndarray) or is_data_array(source):
            dem = checked_array_dem(source, transform, crs, nodata)
            path = array_dem_file(dem)
            store = open_source(path, vdatum=vdatum or "egm96")
            default_name = name or _data_array_name(source) or "array"
        else:
            raise GlobeviewError(
                "add_dem takes a path, a store URL, a numpy array or an xarray DataArray, "
                f"not {type(source).__name__}"
            )
        return self.terrain.add(store, name or default_name)

    def remove_dem(self, name: str) -> None:
        """Remove the DEM layers called ``name`` (one line if there is none)."""
        if name not in self.dems:
            raise GlobeviewError(f"no DEM layer named {name!r} (layers: {self.dems})")
        self.terrain.remove(name)

    # -- overlays --------------------------------------------------------------------------
    def add_overlay(
        self, path: str | os.PathLike[str], layer_type: str | None = None, **style: Any
    ) -> Any:
        """Show a file (GeoJSON, imagery, any file an installed layer type opens) over the
        terrain, on top of the other overlays; ``style`` goes to the layer type (e.g.
        ``color=(r, g, b, a)`` in 0..1, ``width_px=2``). Returns the layer. One line
        (`GlobeviewError`) for a file no layer type opens."""
        from globeview.app.layer_dispatch import parse_layer_spec

        text = os.fspath(path)
        file = Path(parse_layer_spec(text)[1] if layer_type is None else text)
        if not file.is_file():
            raise GlobeviewError(f"add_overlay: no such file: {file}")
        return self.overlay_host.open(text, layer_type, **style)

    @property
    def overlays(self) -> list[Any]:
        """The overlay layers, bottom first (each has ``name``, ``visible``, ``set_visible``)."""
        return list(self.model.overlays)

    def remove_overlay(self, layer: Any) -> None:
        """Take an overlay layer (as `add_overlay` returned it) off the globe."""
        self.overlay_host.remove(layer)

    # -- camera ----------------------------------------------------------------------------
    @property
    def camera(self) -> CameraPose:
        """Where the camera is (`CameraPose`: lon/lat degrees, height metres above WGS84,
        heading/pitch/roll degrees). Set it to a `CameraPose` or a tuple
        ``(lon, lat, height[, heading[, pitch[, roll]]])``."""
        lon, lat, height, heading, pitch, roll = self.model.camera.lonlat_hpr()
        # -1e-14 % 360 is 360.0 in floating point: the pose says 0 for north.
        heading = 0.0 if heading >= 360.0 else heading
        roll = 0.0 if roll >= 360.0 else roll
        return CameraPose(lon, lat, height, heading, pitch, roll)

    @camera.setter
    def camera(self, pose: CameraPose | Sequence[float]) -> None:
        values = (
            (pose.lon, pose.lat, pose.height, pose.heading, pose.pitch, pose.roll)
            if isinstance(pose, CameraPose)
            else tuple(pose)
        )
        if not 3 <= len(values) <= 6:
            raise GlobeviewError(
                "camera takes (lon, lat, height[, heading[, pitch[, roll]]]), "
                f"not {len(values)} numbers"
            )
        self.fly_to(*values)

    def fly_to(
        self,
        lon: float,
        lat: float,
        height: float | None = None,
        heading: float = 0.0,
        pitch: float = -90.0,
        roll: float = 0.0,
    ) -> CameraPose:
        """Put the camera at (lon, lat) degrees, ``height`` metres above the WGS84 ellipsoid
        (default: the current height), looking along ``heading`` (degrees from north,
        clockwise) and ``pitch`` (degrees; -90 straight down). Headless the move is
        immediate; a window showing the globe redraws at once. One line (`GlobeviewError`)
        for a value out of range; the camera then stays."""
        if height is None:
            height = self.camera.height
        fov = self.model.camera.fovy_deg
        try:
            placed = check_lonlat_hpr(lon, lat, height, heading, pitch, roll)
            camera = Camera.from_lonlat(*placed, fovy_deg=fov)
        except (TypeError, ValueError) as exc:
            raise GlobeviewError(f"fly_to: {exc}") from None
        self.model.camera = camera
        self.registry.attach(camera=camera)
        return self.camera

    def view_dems(self) -> CameraPose:
        """Look straight down on the top DEM layer, high enough to see all of it (the
        camera ``globeview render`` starts with)."""
        from globeview.model.camera import camera_for_bounds

        if not self.terrain.layers:
            raise GlobeviewError("view_dems: the globe has no DEM layer")
        bounds = self.terrain.layers[-1].store.bounds
        camera = camera_for_bounds(*bounds, fovy_deg=self.model.camera.fovy_deg)
        return self.fly_to(*camera.lonlat_hpr())

    # -- display, LOD -------------------------------------------------------------------------
    @property
    def display(self) -> DisplaySettings:
        """Display settings (evented): ``exaggeration``, ``wireframe``, ``hillshade``,
        ``fog``, ``background`` (RGB 0..1)."""
        return self.model.display

    @property
    def tau_px(self) -> float:
        """The LOD's screen-space error threshold, pixels (smaller: finer terrain)."""
        return self.model.tau_px

    @tau_px.setter
    def tau_px(self, value: float) -> None:
        try:
            self.model.tau_px = value
        except (TypeError, ValueError) as exc:
            raise GlobeviewError(str(exc)) from None

    @property
    def lod(self) -> str:
        """The active LOD provider's name; setting it is `set_lod` without settings."""
        return self.model.lod

    @lod.setter
    def lod(self, name: str) -> None:
        self.set_lod(name)

    def lod_providers(self) -> list[str]:
        """The names of the LOD providers the enabled plugins offer."""
        return sorted(self.registry.declared(PluginKind.LOD))

    def set_lod(self, name: str, **settings: Any) -> dict[str, Any]:
        """Make ``name`` the LOD provider, with ``settings`` (its setting names -> values,
        e.g. ``set_lod("quadtree-clod", ...)``; see `lod_settings`) for this globe only
        (nothing is stored). Returns the provider's values now. Every name and value is
        checked first: one line (`GlobeviewError`) for an unknown provider, setting or a
        bad value, and nothing changes."""
        if not isinstance(name, str):
            raise GlobeviewError(f"LOD provider name must be text, not {type(name).__name__}")
        check_lod_name(self.registry, name)
        provider = self.registry.find(PluginKind.LOD, name)
        if provider is None:
            why = self.registry.failure_of(name) or "it did not load"
            raise GlobeviewError(f"LOD provider {name} is not available: {why}")
        values = self._checked_settings(name, provider, settings)
        if settings:
            self.registry.invoke(provider, "configure", values)
        self.model.lod = name
        return self.lod_settings()

    def _checked_settings(self, name: str, provider: Any, settings: dict) -> dict[str, Any]:
        """The provider's current values overlaid with ``settings``, each checked."""
        declared = {s.name: s for s in getattr(provider, "settings", ())}
        values = dict(getattr(provider, "values", {}))
        for key, value in settings.items():
            setting = declared.get(key)
            if setting is None:
                offered = ", ".join(declared) or "none"
                raise GlobeviewError(f"{name} has no setting {key!r} (settings: {offered})")
            values[key] = _setting_value(f"{name}.{key}", setting, value)
        return values

    def lod_settings(self) -> dict[str, Any]:
        """The active LOD provider's setting values (name -> value)."""
        provider = self.registry.find(PluginKind.LOD, self.model.lod)
        return dict(getattr(provider, "values", {}) or {})

    # -- tools -------------------------------------------------------------------------------
    def measure(
        self, a: Sequence[float], b: Sequence[float], samples: int | None = None
    ) -> Profile:
        """Measure from A to B, (lon, lat) degrees each, on the terrain shown: the geodesic
        distance, azimuths and the terrain profile (``samples`` points, default the
        ``measure`` tool's setting, 256), as the window's Measure tool does (it is that
        tool's code). One line (`GlobeviewError`) for points that are not (lon, lat) with a
        latitude in -90..90."""
        tool = self.registry.find(PluginKind.TOOL, "measure")
        if tool is None:
            why = self.registry.failure_of("measure", PluginKind.TOOL) or "not enabled"
            raise GlobeviewError(f"measure: the measure tool is not available ({why})")
        if samples is not None:
            n = _checked_samples(tool, samples)
            self.registry.invoke(tool, "configure", {**tool.values, "samples": n})
        failed = object()
        points = [_lonlat("measure: A", a), _lonlat("measure: B", b)]
        # A registry may serve several globes: the tool measures this one's terrain.
        with attached(self.registry, terrain=self.terrain, camera=self.model.camera):
            m = self.registry.invoke(tool, "place_points", points, default=failed, user_errors=True)
        m = getattr(tool, "measurement", None) if m is not failed else None
        if m is None:
            why = self.registry.failure_of("measure", PluginKind.TOOL) or "no measurement"
            raise GlobeviewError(f"measure: the measure tool failed ({why})")
        return Profile(
            a=tuple(m.a),
            b=tuple(m.b),
            distance_m=float(m.distance_m),
            chord_m=float(m.chord_m),
            azimuth_deg=float(m.azimuth_deg),
            back_azimuth_deg=float(m.back_azimuth_deg),
            s_m=np.array(m.profile_s_m, dtype=np.float64),
            lon=np.array(m.profile_lon, dtype=np.float64),
            lat=np.array(m.profile_lat, dtype=np.float64),
            height_m=np.array(m.profile_h_m, dtype=np.float64),
            ellipsoidal_m=np.array(m.profile_ellipsoidal_m, dtype=np.float64),
        )

    def height_at(self, lon: float, lat: float) -> float:
        """The terrain height (metres above the WGS84 ellipsoid) at (lon, lat) degrees, from
        the finest level any DEM has, as `globeview height` answers it; NaN where no DEM has
        terrain there (the bare ellipsoid is not an elevation). One line
        (`GlobeviewError`) for a point that is not on the globe."""
        lon = _lonlat("height_at: the point", (lon, lat))[0]
        if not self.terrain.visible_layers:
            return math.nan
        answer = query_heights(self.terrain, np.array([lon]), np.array([lat]))[0]
        return math.nan if answer.ellipsoidal is None else answer.ellipsoidal

    # -- rendering ---------------------------------------------------------------------------
    def render(self, size: tuple[int, int] | None = None) -> np.ndarray:
        """Draw the globe headless (OpenGL through EGL; Mesa's llvmpipe needs no GPU) and
        return the picture: (height, width, 4) uint8 RGBA, row 0 at the top. ``size`` is
        (width, height) pixels (default: the last size, first `DEFAULT_SIZE`). Every tile
        of the view is loaded before the picture is taken. One line (`RenderError`) when no
        headless OpenGL context can be made (no EGL)."""
        size = _checked_size(size or self._size)
        self._size = size
        if self._gl is None:
            self._gl = _Headless(self)
            # A globe dropped without close() still releases its GL objects and context.
            self._release = weakref.finalize(self, _release_quietly, self._gl)
        rgb = self._gl.draw(size)
        alpha = np.full((*rgb.shape[:2], 1), 255, dtype=np.uint8)
        return np.concatenate([rgb, alpha], axis=2)

    def save(self, path: str | os.PathLike[str], size: tuple[int, int] | None = None) -> Path:
        """Render (`render`) and write a PNG to ``path``, atomically (nothing is left on
        failure). One line (`GlobeviewError`) for a path that cannot be written."""
        from PIL import Image

        from globeview.fileio import atomic_outputs, check_output_file

        out = check_output_file(path, "save", (".png",))
        image = Image.fromarray(self.render(size), "RGBA")
        with atomic_outputs([out]) as (tmp,):
            image.save(tmp, format="PNG")
        return Path(out)

    def close(self) -> None:
        """Release the headless OpenGL objects (the model stays usable; the next `render`
        makes them again)."""
        if self._gl is not None:
            self._gl = None
            self._release()

    @property
    def session(self) -> GlobeSession | None:
        """The headless `GlobeSession` drawing this globe (None before the first render).
        Its GL side lives on the API's GL thread: read its state (``session.last.stats``),
        draw through `render`."""
        return None if self._gl is None else self._gl.session

    def _pick(self, x_px: float, y_px: float) -> Any:
        """The terrain point (`Pick`: ECEF, lon, lat, height) under a pixel of the last
        render, or None (sky, or nothing rendered yet)."""
        return None if self._gl is None else self._gl.pick(x_px, y_px)

    # -- notebooks ---------------------------------------------------------------------------
    def _repr_png_(self) -> bytes | None:
        """The globe as a PNG (Jupyter shows it): the last size rendered. None (Jupyter
        falls back to the text) when no headless OpenGL can be made; the reason is logged."""
        from globeview.app.notebook import png_bytes

        return png_bytes(self)

    def widget(self, size: tuple[int, int] = (800, 500)) -> Any:
        """An interactive view for Jupyter (jupyter_rfb, drawn with EGL in the kernel): drag
        to orbit, wheel to zoom. Needs ``pip install globeview[notebook]``."""
        from globeview.app.notebook import GlobeRfbWidget

        return GlobeRfbWidget(self, _checked_size(size))

    def __repr__(self) -> str:
        c = self.camera
        return (
            f"<globeview.Globe dems={self.dems} overlays={len(self.model.overlays)} "
            f"lod={self.lod!r} camera=({c.lon:.4f}, {c.lat:.4f}, {c.height:.0f} m)>"
        )

    def __enter__(self) -> Globe:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class _Headless:
    """The globe's EGL context, session and offscreen target (made on first render).

    Every GL call runs on one worker thread (`gl_call`), never on the caller's: a thread
    that has had an EGL context current cannot make a GLX context current any more
    (libglvnd), so the caller's thread stays free for a Qt window (`globeview.show`, IPython's
    ``%gui qt``), and the window's context never meets this one on a thread."""

    def __init__(self, globe: Globe) -> None:
        self.target: Any = None
        gl_call(self._make, globe)

    def _make(self, globe: Globe) -> None:
        from globeview.app.session import GlobeSession
        from globeview.render.offscreen import create_headless_context

        self.ctx = create_headless_context(fresh=True)  # RenderError (one line) without EGL
        # The session attaches itself to the registry; a window sharing it keeps its own
        # (each frame of ours attaches ours for its duration: `_draw`).
        host = globe.registry.host_objects()
        with self.ctx, attached(globe.registry, **host):
            try:
                self.session = GlobeSession(
                    self.ctx,
                    globe.terrain,
                    registry=globe.registry,
                    globe=globe.model,
                    overlay_host=globe.overlay_host,
                )
            except BaseException:
                self.ctx.release()
                raise

    def draw(self, size: tuple[int, int]) -> np.ndarray:
        """One frame at ``size``, every tile loaded first: (h, w, 3) uint8 RGB."""
        return gl_call(self._draw, size)

    def _draw(self, size: tuple[int, int]) -> np.ndarray:
        from globeview.render.offscreen import OffscreenTarget

        with self.ctx:
            if self.target is None or self.target.size != size:
                if self.target is not None:
                    self.target.release()
                self.target = OffscreenTarget(self.ctx, size)
            session = self.session
            # A registry may serve several globes (and a window): for this frame plugins see
            # this one's session, then the host they saw before (a window's redraw hooks).
            with attached(
                session.registry,
                scene=session,
                terrain=session.terrain,
                camera=session.camera,
                renderer=session.hooks,
            ):
                return self._frame(session, size)

    def _frame(self, session: GlobeSession, size: tuple[int, int]) -> np.ndarray:
        """Draw ``session`` into the target, every tile loaded: (h, w, 3) uint8 RGB."""
        remote = any(bool(getattr(ly.store, "is_remote", False)) for ly in session.terrain.layers)
        session.renderer.async_loading = remote
        result = session.render(self.target.fbo, size)
        while remote and result.stats.tiles_loading:
            # Remote tiles arrive on the loader's worker; coarser ones stand in meanwhile.
            time.sleep(0.02)
            result = session.render(self.target.fbo, size)
        if session.overlay_errors:
            raise GlobeviewError(session.take_overlay_errors()[0])
        return self.target.read_rgb()

    def pick(self, x_px: float, y_px: float) -> Any:
        """The terrain point under a pixel of the last frame (`GlobeSession.pick`)."""
        if self.session.last is None:
            return None

        def pick() -> Any:
            with self.ctx:
                return self.session.pick(x_px, y_px)

        return gl_call(pick)

    def release(self) -> None:
        def release() -> None:
            with self.ctx:
                if self.target is not None:
                    self.target.release()
                self.session.release_gl()
            self.ctx.release()

        gl_call(release)


def _release_quietly(gl: _Headless) -> None:
    """Release a dropped globe's GL side; nothing to do once the interpreter is ending (the
    GL thread takes no more work then, and the process takes its context with it)."""
    with contextlib.suppress(RuntimeError):  # "cannot schedule new futures after shutdown"
        gl.release()


@contextlib.contextmanager
def attached(registry: PluginRegistry, **host: Any) -> Iterator[None]:
    """``registry.attach(**host)`` for the block, then what plugins saw before."""
    before = registry.host_objects()
    registry.attach(**host)
    try:
        yield
    finally:
        registry.attach(**{k: before[k] for k in host})


#: The one thread every headless GL call of the API runs on (see `_Headless`).
_GL_THREAD: list[ThreadPoolExecutor] = []


def gl_call(fn: Callable[..., Any], *args: Any) -> Any:
    """``fn(*args)`` on the API's GL thread, its result or exception returned here."""
    if not _GL_THREAD:
        _GL_THREAD.append(ThreadPoolExecutor(1, thread_name_prefix="globeview-egl"))
    return _GL_THREAD[0].submit(fn, *args).result()


def _embedded_terrain() -> TerrainStack:
    """The shipped DEMs as a stack named after their files (ingested once)."""
    from globeview.terrain.dem.data import embedded_dem_paths
    from globeview.terrain.embedded import embedded_stores

    return TerrainStack.from_stores(embedded_stores(), [p.stem for p in embedded_dem_paths()])


def _data_array_name(source: Any) -> str | None:
    """A DataArray's own name, if it has a usable one."""
    name = getattr(source, "name", None) if is_data_array(source) else None
    return str(name) if isinstance(name, str) and name.strip() else None


def _lonlat(label: str, point: Sequence[float]) -> tuple[float, float]:
    """A (lon, lat) point, checked: one line for anything else."""
    try:
        lon, lat = (float(v) for v in point)
    except (TypeError, ValueError):
        raise GlobeviewError(f"{label} must be (lon, lat) degrees, not {point!r:.60}") from None
    if not (math.isfinite(lon) and math.isfinite(lat)) or abs(lat) > 90.0:
        raise GlobeviewError(
            f"{label} = ({lon:g}, {lat:g}): longitude must be finite and latitude "
            "in -90..90 degrees"
        )
    return lon, lat


def _checked_samples(tool: Any, samples: Any) -> int:
    """``samples`` as the measure tool's setting takes it; one line if refused."""
    setting = next((s for s in getattr(tool, "settings", ()) if s.name == "samples"), None)
    if setting is None:
        raise GlobeviewError("measure: this measure tool has no samples setting")
    return int(_setting_value("measure: samples", setting, samples))


def _setting_value(label: str, setting: Any, value: Any) -> Any:
    """``value`` for a plugin `Setting`, checked strictly as ``--set`` checks it (a number
    outside min..max, a fraction for an integer, a choice not offered are refused, not
    clamped); one `GlobeviewError` line naming ``label`` and the valid values."""
    from globeview.plugins.settings import parse_setting_value, setting_problem

    try:
        if setting.type == "bool":
            if not isinstance(value, bool):
                raise ValueError(f"{value!r:.40} is not True or False")
            return value
        if isinstance(value, bool) or not isinstance(value, (str, int, float, np.number)):
            raise ValueError(f"{value!r:.40} is not a {setting.type}")
        return parse_setting_value(
            setting, repr(float(value)) if isinstance(value, float) else str(value)
        )
    except ValueError as exc:
        raise GlobeviewError(f"{label}: {setting_problem(setting, exc)}") from None


def _checked_size(size: Any) -> tuple[int, int]:
    """(width, height) pixels, each a whole number in `SIZE_RANGE_PX`; one line if not."""
    lo, hi = SIZE_RANGE_PX
    try:
        w, h = size
        if any(isinstance(v, bool) or int(v) != v for v in (w, h)):
            raise ValueError
        w, h = int(w), int(h)
    except (TypeError, ValueError):
        raise GlobeviewError(f"size must be (width, height) in pixels, not {size!r:.60}") from None
    if not (lo <= w <= hi and lo <= h <= hi):
        raise GlobeviewError(f"size {w}x{h} is out of range ({lo}..{hi} pixels a side)")
    return w, h
