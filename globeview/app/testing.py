"""pytest fixtures for testing globeview plugins headless (a pytest plugin, ``pytest11``).

Installed with globeview, so a plugin's own test suite gets these fixtures with no conftest:

- ``globeview_config_dir``: a fresh config directory (``$GLOBEVIEW_CONFIG_DIR``) per test.
- ``globeview_registry``: a `PluginRegistry` on that directory, discovery done.
- ``headless_view``: a function ``(lon, lat, height, heading=0, pitch=-90, viewport=(800,
  600), **kw) -> ViewState`` for a camera at a geodetic position (degrees, metres).
- ``plugin_site``: a temporary site directory on ``sys.path`` where tests write throwaway
  plugin distributions (package + ``.dist-info`` with ``entry_points.txt``) that
  `importlib.metadata` discovers like pip-installed ones.
- ``globeview_terrain`` (session): the embedded terrain — the global base and the regional
  DEMs shipped with globeview — as a `TerrainStack`, ingested once per test session into a
  temporary cache (never the user's). Hand it to a provider's ``select(view, terrain)``.
- ``globeview_gl`` (session): a headless OpenGL context (Mesa EGL works); the test is skipped
  where there is none. A test using it fails if it leaks GL objects (made through
  `globeview.render.gpu_objects` and dropped unreleased).
- ``rendered``: a function rendering one headless frame of the embedded terrain with a given
  LOD provider, tool (and its points) and settings; returns a `RenderedFrame` (the image as a
  numpy array, the frame's stats, which provider drew and why another failed).

Nothing heavy is imported when pytest loads this module; each fixture imports what it needs.
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.util
import os
import sys
import textwrap
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

if TYPE_CHECKING:
    import moderngl
    import numpy as np

    from globeview.lod.render_set import RenderSet
    from globeview.lod.view_state import ViewState
    from globeview.model.camera import Camera
    from globeview.plugins.registry import PluginRegistry
    from globeview.terrain.compose.stack import TerrainStack

__all__ = [
    "PluginSite",
    "RenderedFrame",
    "globeview_config_dir",
    "globeview_gl",
    "globeview_registry",
    "globeview_terrain",
    "headless_view",
    "make_view",
    "plugin_site",
    "render_frame",
    "rendered",
]


def make_view(
    lon: float,
    lat: float,
    height: float,
    heading: float = 0.0,
    pitch: float = -90.0,
    viewport: tuple[int, int] = (800, 600),
    *,
    fovy_deg: float = 45.0,
    tau_px: float = 2.0,
    exaggeration: float = 1.0,
    speed_mps: float = 0.0,
) -> ViewState:
    """A `ViewState` for a camera at (lon, lat) degrees, ``height`` metres above WGS84,
    looking along (heading, pitch) degrees (pitch -90 = straight down)."""
    from globeview.lod.view_state import ViewState
    from globeview.model.camera import Camera

    cam = Camera.from_lonlat(lon, lat, height, heading, pitch, fovy_deg=fovy_deg)
    return ViewState.from_camera(
        cam, viewport, tau_px=tau_px, exaggeration=exaggeration, speed_mps=speed_mps
    )


@pytest.fixture
def globeview_config_dir(tmp_path_factory: pytest.TempPathFactory, monkeypatch) -> Path:
    """An empty config directory, set as ``$GLOBEVIEW_CONFIG_DIR`` for the test."""
    d = tmp_path_factory.mktemp("globeview-config")
    monkeypatch.setenv("GLOBEVIEW_CONFIG_DIR", str(d))
    return d


@pytest.fixture
def globeview_registry(
    globeview_config_dir: Path, request: pytest.FixtureRequest
) -> PluginRegistry:
    """A plugin registry persisting to the test's config dir, with discovery done. When the
    test also uses ``globeview_terrain``, the contributions it creates get that terrain in
    their context (``context.terrain``), as the window's and ``render``'s do; otherwise
    None (the embedded terrain is ingested only for the tests that ask for it)."""
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import JsonFileSettings

    registry = PluginRegistry(JsonFileSettings(globeview_config_dir / "settings.json"))
    registry.discover()
    if "globeview_terrain" in request.fixturenames:
        registry.attach(terrain=request.getfixturevalue("globeview_terrain"))
    return registry


@pytest.fixture
def headless_view() -> Callable[..., ViewState]:
    """`make_view`: builds a ViewState for a camera at lon/lat/height."""
    return make_view


def plugin_manifest(
    name: str,
    package: str,
    kind: str = "lod",
    attr: str = "Provider",
    description: str = "test plugin",
) -> str:
    """The TOML manifest of a one-contribution plugin whose contribution is
    ``package.impl:attr`` (for `PluginSite.add` and plugin tests)."""
    return f"""
        name = "{name}"
        version = "0.0.1"
        description = "{description}"
        kinds = ["{kind}"]
        api_version = "1.0"

        [[contributions]]
        name = "{name}"
        kind = "{kind}"
        target = "{package}.impl:{attr}"
        """


class PluginSite:
    """A directory on ``sys.path`` holding throwaway plugin distributions.

    ``add`` writes a package and a ``<dist>.dist-info`` directory with ``METADATA`` and
    ``entry_points.txt``: the same files pip writes, so discovery finds the plugin through
    `importlib.metadata.entry_points` as it finds a pip-installed one.
    """

    def __init__(self, root: Path) -> None:
        self.root = root
        self.packages: list[str] = []

    def add(
        self,
        package: str,
        manifest: str,
        modules: dict[str, str] | None = None,
        *,
        entry_name: str | None = None,
        dist_name: str | None = None,
        version: str = "0.1.0",
        manifest_file: str = "globeview.toml",
    ) -> Path:
        """Write plugin package ``package`` with ``manifest`` (TOML text) and ``modules``
        ({relative module path, e.g. "__init__" or "tools": source}) and register its entry
        point ``entry_name`` (default: the manifest's name, else the package name).
        Returns the package directory."""
        import tomllib

        pkg_dir = self.root / package
        pkg_dir.mkdir(parents=True, exist_ok=True)
        mods = {"__init__": ""} | dict(modules or {})
        for rel, src in mods.items():
            path = pkg_dir.joinpath(*rel.split(".")).with_suffix(".py")
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(textwrap.dedent(src), encoding="utf-8")
            # A module rewritten within the second of its last import, at the same length,
            # would pass the bytecode cache's check (whole-second mtime + size) and run the old
            # code: drop its cached bytecode (the cache prefix included).
            with contextlib.suppress(OSError):
                os.unlink(importlib.util.cache_from_source(str(path)))
        manifest_text = textwrap.dedent(manifest)
        (pkg_dir / manifest_file).write_text(manifest_text, encoding="utf-8")
        if entry_name is None:
            try:
                entry_name = str(tomllib.loads(manifest_text).get("name") or package)
            except tomllib.TOMLDecodeError:
                entry_name = package
        dist = dist_name or package.replace("_", "-")
        info = self.root / f"{dist.replace('-', '_')}-{version}.dist-info"
        info.mkdir(exist_ok=True)
        (info / "METADATA").write_text(
            f"Metadata-Version: 2.1\nName: {dist}\nVersion: {version}\n", encoding="utf-8"
        )
        (info / "entry_points.txt").write_text(
            f"[globeview.plugins]\n{entry_name} = {package}:{manifest_file}\n", encoding="utf-8"
        )
        self.packages.append(package)
        importlib.invalidate_caches()
        return pkg_dir

    def forget_modules(self) -> None:
        """Remove the site's packages from ``sys.modules``."""
        for name in list(sys.modules):
            if name.split(".")[0] in self.packages:
                del sys.modules[name]


@pytest.fixture
def plugin_site(tmp_path_factory: pytest.TempPathFactory, monkeypatch) -> Iterator[PluginSite]:
    """A `PluginSite` on ``sys.path`` for this test; its modules are unloaded afterwards."""
    root = tmp_path_factory.mktemp("plugin-site")
    monkeypatch.syspath_prepend(str(root))
    site = PluginSite(root)
    yield site
    site.forget_modules()
    importlib.invalidate_caches()


# -- real terrain and headless frames --------------------------------------------------------
@pytest.fixture(scope="session")
def globeview_terrain(tmp_path_factory: pytest.TempPathFactory) -> TerrainStack:
    """The embedded terrain (global base first, then the regional DEMs: White Mountains SRTM,
    Crater Lake, Vancouver) as a `TerrainStack`, heights in metres above WGS84.

    The stores are ingested once per test session into a temporary cache directory, so a
    plugin's tests neither need nor touch the user's cache (a few seconds, once)."""
    from globeview.terrain.compose.stack import TerrainStack
    from globeview.terrain.embedded import embedded_stores

    cache = tmp_path_factory.mktemp("globeview-cache")
    with pytest.MonkeyPatch.context() as mp:  # session scope: no `monkeypatch` fixture
        mp.setenv("GLOBEVIEW_CACHE_DIR", str(cache))
        stores = embedded_stores()
    return TerrainStack.from_stores(stores)


@pytest.fixture(scope="session")
def globeview_gl() -> Iterator[moderngl.Context]:
    """A headless moderngl context for the session; skips the test where OpenGL is missing."""
    from globeview.render.offscreen import (
        RenderError,
        create_headless_context,
        release_headless_context,
    )

    try:
        ctx = create_headless_context()
    except RenderError as exc:  # pragma: no cover - depends on the machine
        pytest.skip(f"no headless OpenGL: {exc}")
    yield ctx
    release_headless_context(ctx)


@pytest.fixture(autouse=True)
def _globeview_gl_leak_check(request: pytest.FixtureRequest) -> Iterator[None]:
    """Fails a test that uses ``globeview_gl`` and leaks GL objects: objects made during
    the test (through `globeview.render.gpu_objects`), never released, that nothing
    references any more (no code can free them). Objects a live holder keeps (a shared
    scene's caches, a module-scoped target) are not leaks. The leaked objects are released
    after the report, so the next test starts clean."""
    if "globeview_gl" not in request.fixturenames:
        yield
        return
    from globeview.render.gpu_objects import gpu_objects

    tracker = gpu_objects(request.getfixturevalue("globeview_gl"))
    mark = tracker.mark
    yield
    leaked = tracker.leaked_since(mark)
    if leaked:
        tracker.release_leaked(leaked)
        names = ", ".join(sorted({str(t) for t in leaked}))
        pytest.fail(f"GL objects leaked by this test ({len(leaked)}): {names}", pytrace=False)


@dataclass
class RenderedFrame:
    """One headless frame (what `rendered` returns).

    Attributes:
        image: (height, width, 3) uint8 RGB, row 0 at the top.
        stats: the frame's figures as ``globeview render --stats`` writes them (triangles,
            tiles_drawn, lod_ms, ..., and the provider's name).
        provider: the LOD provider that drew the frame (not the requested one after a
            fallback).
        requested: the LOD provider asked for.
        render_set: the `RenderSet` that was drawn.
        failures: contribution name -> ``"ExcType: message"`` of the provider or tool of this
            frame that failed (empty when both worked).
        session: the `GlobeSession` (its registry, camera, terrain) for further checks;
            ``session.pick(x, y)`` gives the terrain point under a pixel of this frame
            (pixels from the top-left; a `Pick` with ``lon``, ``lat`` degrees, ``height`` m
            above WGS84, ``ecef``, ``on_terrain``). None once `rendered` has drawn the next
            frame (it released this one's GL objects); `release` does that by hand.
    """

    image: np.ndarray
    stats: dict[str, Any]
    provider: str
    requested: str
    render_set: RenderSet
    failures: dict[str, str] = field(default_factory=dict)
    session: Any = field(default=None, repr=False)
    #: The framebuffer the frame was drawn into: picking reads its depth, so it lives as
    #: long as the session (it was released at once, and ``session.pick`` raised).
    target: Any = field(default=None, repr=False)

    @property
    def fell_back(self) -> bool:
        """True when the requested provider did not draw the frame."""
        return self.provider != self.requested

    def release(self) -> None:
        """Release the frame's GL objects (the session's tile pool, the target); the image
        and stats stay. Idempotent; `rendered` calls it for the previous frame."""
        if self.session is not None:
            self.session.release_gl()
            self.session = None
        if self.target is not None:
            self.target.release()
            self.target = None


def render_frame(
    ctx: moderngl.Context,
    terrain: TerrainStack,
    registry: PluginRegistry,
    lod: str = "chunked-sse",
    *,
    tool: str | None = None,
    points: Sequence[tuple[float, float]] = (),
    settings: Mapping[str, Mapping[str, Any]] | None = None,
    camera: Camera | Sequence[float] | None = None,
    size: tuple[int, int] = (320, 240),
    tau_px: float | None = None,
    exaggeration: float = 1.0,
    fovy_deg: float = 45.0,
) -> RenderedFrame:
    """Render one frame headless, as ``globeview render`` does, and return it.

    Args:
        lod: the LOD provider's contribution name.
        tool: a tool to activate (its overlay is drawn over the frame), with ``points``
            (lon, lat degrees) given to it as ``render --tool NAME --points`` does.
        settings: contribution name -> {setting name: value}, applied (and persisted in
            the registry's settings) before the frame; a name that is not an enabled
            contribution, or a key that is not one of its settings, raises KeyError, a
            value its `Setting` refuses (wrong type, not a choice) ValueError.
        camera: a `Camera`, or (lon, lat, height[, heading, pitch]) in degrees and metres
            above WGS84 (pitch -90: straight down); default: the whole globe from 20,000 km.
        size: (width, height) pixels.

    The frame keeps its session and target for picking (``frame.session.pick``); release
    them with `RenderedFrame.release` (the `rendered` fixture does) when frames are many.
    """
    from globeview.app.session import GlobeSession
    from globeview.model.camera import Camera
    from globeview.render.offscreen import OffscreenTarget

    for name, values in (settings or {}).items():
        _configure(registry, name, values)
    if camera is None:
        camera = Camera.from_lonlat(0.0, 20.0, 2.0e7, fovy_deg=fovy_deg)
    elif not isinstance(camera, Camera):
        camera = Camera.from_lonlat(*(float(v) for v in camera), fovy_deg=fovy_deg)
    session = GlobeSession(ctx, terrain, camera, registry=registry, lod=lod)
    if tau_px is not None:
        session.tau_px = float(tau_px)
    session.settings.exaggeration = float(exaggeration)
    target = OffscreenTarget(ctx, size)
    try:
        if tool is not None:
            # A tool that fails to load is reported in `failures` (as `render --tool` says
            # it in its 'wrote' line); a name no plugin declares raises GlobeviewError.
            if session.find_tool(tool) is not None or registry.failure_of(tool) is None:
                session.activate_tool(tool)
            if points and session.tool() is not None:
                from globeview.app.headless import place_points

                place_points(session, session.tool(), list(points), size)
        # The first frame uploads tiles; the second is the steady-state frame (as `render`).
        session.render(target.fbo, size)
        session.reset_lod()
        result = session.render(target.fbo, size)  # the tool's overlay included
        image = target.read_rgb()
    except BaseException:
        target.release()
        session.release_gl()
        raise
    stats = dict(result.stats.as_dict())
    failures = {
        name: why
        for name in (lod, tool)
        if name is not None and (why := registry.failure_of(name)) is not None
    }
    return RenderedFrame(
        image=image,
        stats=stats,
        provider=result.stats.lod_provider,
        requested=lod,
        render_set=result.render_set,
        failures=failures,
        session=session,
        target=target,  # the session's last frame's depth: what `session.pick` reads
    )


def _configure(registry: PluginRegistry, name: str, values: Mapping[str, Any]) -> None:
    """Apply and persist setting ``values`` of contribution ``name`` (any kind), on top of
    its stored ones; KeyError for an unknown contribution or setting (a typo in a test
    must not pass silently with the defaults)."""
    from globeview.plugins.api import PluginKind

    instance = next(
        (i for k in PluginKind if (i := registry.find(k, name)) is not None),
        None,
    )
    if instance is None:
        raise KeyError(f"no enabled contribution named {name!r}")
    known = {s.name: s for s in getattr(instance, "settings", ())}
    unknown = sorted(set(values) - set(known))
    if unknown:
        raise KeyError(f"{name} has no setting {', '.join(unknown)} (has: {sorted(known)})")
    for key, value in values.items():
        try:
            known[key].coerce(value)
        except (TypeError, ValueError) as exc:  # the host would silently use the default
            raise ValueError(f"{name}.{key}: {exc}") from None
    plugin, _ = registry.contribution_of(instance)
    stored = registry.settings.get(f"plugins/{plugin}/contributions/{name}", {})
    registry.configure(instance, {**(stored if isinstance(stored, dict) else {}), **values})


@pytest.fixture
def rendered(
    globeview_gl: moderngl.Context,
    globeview_terrain: TerrainStack,
    globeview_registry: PluginRegistry,
) -> Iterator[Callable[..., RenderedFrame]]:
    """`render_frame` on the session's GL context, the embedded terrain and the test's
    registry: ``rendered("my-provider", camera=(lon, lat, height), tool="my-tool",
    settings={"my-provider": {"level": 5}})`` -> `RenderedFrame`.

    Each frame's `GlobeSession` holds a GPU tile pool (~130 MB on llvmpipe), so only the
    latest frame keeps its session: rendering the next frame releases the previous one's
    GL objects and sets its ``session`` to None (its image and stats stay). The last
    session is released after the test."""
    frames: list[RenderedFrame] = []

    def release_previous() -> None:
        while frames:
            frames.pop().release()

    def render(lod: str = "chunked-sse", **kwargs: Any) -> RenderedFrame:
        release_previous()
        frame = render_frame(globeview_gl, globeview_terrain, globeview_registry, lod, **kwargs)
        frames.append(frame)
        return frame

    yield render
    release_previous()
