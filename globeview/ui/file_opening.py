"""Opening data in the window: File > Open DEM… / Open Overlay… / Open URL… / Open Recent,
drag and drop and the command line's files, decided by content (`classify_path`): GeoJSON
and RGB(A)/paletted rasters are overlays, single-band numeric rasters and tile store folders
are DEMs. DEMs and stores load in the background (`DemLoader`; their progress and a Cancel
button in the status bar) and become the top terrain layer; stores served over HTTP are
remembered in Open Recent like files (their tiles stream in, those that fail stay stood in by
coarser ones). Overlays open at once through the window's `OverlayHost`, with or without GL.
"""

from __future__ import annotations

import threading
import urllib.parse
from pathlib import Path
from typing import Any

from PyQt6.QtCore import QSettings, QTimer
from PyQt6.QtGui import QAction, QKeySequence
from PyQt6.QtWidgets import QFileDialog, QLabel, QMainWindow, QMenu, QProgressBar, QPushButton

from globeview.app.layer_dispatch import choose_layer_type
from globeview.app.overlay_host import OverlayHost
from globeview.errors import GlobeviewError
from globeview.model.globe import Globe
from globeview.plugins.registry import PluginRegistry
from globeview.terrain.sources import check_store_url, is_store_url
from globeview.terrain.store.tile_store import TileStore
from globeview.ui.errors import ErrorReporter
from globeview.ui.globe_widget import GlobeWidget
from globeview.ui.layer_panel import LayerPanel
from globeview.ui.loading import DemLoader, missing_path_error
from globeview.ui.open_url import ask_store_url
from globeview.ui.status import StatusBar
from globeview.ui.vector_layer_dialog import ask_vector_layer

MAX_RECENT = 10
DEM_FILTER = (
    "DEM rasters (*.tif *.tiff *.hgt *.dem *.asc *.img *.vrt *.nc *.bil *.dt0 *.dt1 *.dt2);;"
    "All files (*)"
)


#: Milliseconds after the window is built by which the embedded overlays are opened even if
#: no complete view was drawn by then (a tile that never loads must not keep the borders off).
EMBEDDED_OVERLAYS_LATEST_MS = 5000


class FileOpening:
    """What the window opens and how: the File menu's open actions and recent files, the
    background DEM loader with its progress in the status bar, overlays.

    Args:
        window: the dialogs' parent and the actions' owner.
        model: the `Globe` (its terrain gets the DEMs; its overlays are opened onto it).
        registry: the plugin registry whose layer types decide what a file is.
        overlay_host: opens overlay files onto ``model``.
        globe: the `GlobeWidget` (it flies over a DEM just opened).
        layer_panel: selects what was opened; its datum choice applies to DEMs.
        status, errors: one-line notices and errors.
        qsettings: where the recent files persist (``files/recent``).
    """

    def __init__(
        self,
        window: QMainWindow,
        model: Globe,
        registry: PluginRegistry,
        overlay_host: OverlayHost,
        globe: GlobeWidget,
        layer_panel: LayerPanel,
        status: StatusBar,
        errors: ErrorReporter,
        qsettings: QSettings,
    ) -> None:
        self.window = window
        self.model = model
        self.terrain = model.terrain
        self.registry = registry
        self.overlay_host = overlay_host
        self.globe = globe
        self.layer_panel = layer_panel
        self.status = status
        self.errors = errors
        self.qsettings = qsettings
        #: How File > Open URL… asks for the URL: ``ask_url(parent, initial) -> str | None``
        #: (the checked URL or None when cancelled); tests put a function of their own here.
        self.ask_url = ask_store_url
        #: How opening a GIS file of several layers asks which: ``ask_layer(parent, file name,
        #: [(layer, geometry type), ...]) -> layer | None`` (None: cancelled); tests replace it.
        self.ask_layer = ask_vector_layer
        self._embedded_pending = False  # `open_embedded_overlays_after_first_view`

        # The File menu's entries (the window places them).
        self.open_action = QAction("&Open DEM…", window)
        self.open_action.setShortcut(QKeySequence.StandardKey.Open)
        self.open_action.triggered.connect(self.open_dialog)
        self.open_overlay_action = QAction("Open &Overlay…", window)
        self.open_overlay_action.setShortcut(QKeySequence("Ctrl+Shift+O"))
        self.open_overlay_action.setToolTip(
            "Drape imagery or a thematic raster, or show GeoJSON or GIS vector files "
            "(Shapefile, GeoPackage, KML, GPX, FlatGeobuf...)"
        )
        self.open_overlay_action.triggered.connect(self.open_overlay_dialog)
        self.open_url_action = QAction("Open &URL…", window)
        self.open_url_action.setShortcut(QKeySequence("Ctrl+U"))
        self.open_url_action.setToolTip(
            "Open a tile store served over HTTP(S) by its URL (tiles stream in as needed)"
        )
        self.open_url_action.triggered.connect(self.open_url_dialog)
        self.recent_menu = QMenu("Open &Recent", window)
        self._update_recent_menu()

        # The loader and its progress in the status bar (shown while it works).
        self.load_bar = QProgressBar()
        self.load_bar.setMaximumWidth(160)
        self.load_label = QLabel()
        self.cancel_button = QPushButton("Cancel")
        self.cancel_button.setToolTip("Cancel opening the DEM")
        for w in (self.load_label, self.load_bar, self.cancel_button):
            status.addWidget(w)
            w.hide()
        self.loader = DemLoader(window)
        self.loader.started.connect(self._load_started)
        self.loader.progress.connect(self._load_progress)
        self.loader.loaded.connect(self._loaded)
        self.loader.failed.connect(self._load_failed)
        self.loader.cancelled.connect(
            lambda p: self.errors.notify(f"opening {Path(p).name} cancelled")
        )
        self.loader.idle.connect(self._load_idle)
        self.cancel_button.clicked.connect(self.loader.cancel)

    # -- DEMs and stores --------------------------------------------------------------------

    def open_dialog(self) -> None:
        start = str(Path(self.recent_files()[0]).parent) if self.recent_files() else ""
        paths, _ = QFileDialog.getOpenFileNames(self.window, "Open DEM", start, DEM_FILTER)
        self.open_dems(paths)

    def open_paths(self, paths: list[str] | tuple[str, ...]) -> None:
        """Open files deciding by content (`classify_path`): DEMs and tile store folders load
        in the background, overlays are added at once. The path drag and drop, recent files
        and the command line take; a file of neither kind reports its one-line error."""
        for p in paths:
            if not p:
                continue
            if is_store_url(str(p)):  # a store over HTTP (a recent URL, a dropped link)
                self.open_url(str(p))
                continue
            try:
                kind = classify_path(p, self.registry)
            except GlobeviewError as exc:
                self.errors.error(exc)
                continue
            if kind == "overlay":
                self.open_overlay(str(p))
            else:
                self.open_dems([str(p)])

    def open_dems(self, paths: list[str] | tuple[str, ...]) -> None:
        """Open DEM files (or tile store folders) in the background (File > Open DEM…)."""
        vdatum = self.layer_panel.vdatum()
        for p in paths:
            if p:
                self.loader.load(str(p), vdatum)

    def open_url_dialog(self) -> None:
        """File > Open URL…: ask for a store URL (the last one opened filled in) and open it."""
        last = next((f for f in self.recent_files() if is_store_url(f)), "")
        url = self.ask_url(self.window, last)
        if url:
            self.open_url(url)

    def open_url(self, text: str) -> bool:
        """Open the tile store at URL ``text`` in the background (its manifest is fetched by
        the loader's worker thread, never on the UI thread). A URL of the wrong form
        (`check_store_url`: ftp://, file://, no host, a bad port) is one line in a dialog at
        once; an unreachable server or a folder that is not a store is one line when the
        loader gives up (`_load_failed`). Returns whether the load was queued."""
        try:
            url = check_store_url(text)
        except GlobeviewError as exc:
            self.errors.error(exc)
            return False
        self.loader.load(url)
        return True

    # -- overlays ----------------------------------------------------------------------------

    def open_overlay_dialog(self) -> None:
        """File > Open Overlay…: any file an enabled layer type opens (built-in or installed);
        the filter lists every layer type's patterns (`layer_dispatch.overlay_file_filter`)."""
        start = str(Path(self.recent_files()[0]).parent) if self.recent_files() else ""
        name_filter = self.overlay_host.file_filter()
        paths, _ = QFileDialog.getOpenFileNames(self.window, "Open Overlay", start, name_filter)
        self.open_overlays(paths)

    def open_overlays(self, paths: list[str] | tuple[str, ...]) -> list:
        """Open files as overlays (the Open Overlay dialog's path); returns the layers added."""
        layers = [self.open_overlay(str(p)) for p in paths if p]
        return [ly for ly in layers if ly is not None]

    def open_overlay(self, path: str) -> Any:
        """Add a raster or GeoJSON file as an overlay layer (its type decided by content) on
        top of the overlays; a bad file reports its one-line error and changes nothing.
        Returns the layer (None on error). No GL: it works before the globe's GL is up."""
        try:
            chosen = self._vector_layer_choice(str(path))
            if chosen is None:
                return None
            # No GL here: the layer's GPU side is made at the next frame.
            layer = self.overlay_host.open(chosen)  # listed by the model's event
        except Exception as exc:  # noqa: BLE001  any failure is one line in a dialog, the window keeps working
            self.errors.error(exc, "" if isinstance(exc, GlobeviewError) else "opening overlay")
            return None
        self.layer_panel.overlays.select(layer)
        self.status.notice(f"added {layer.kind} overlay {layer.name}")
        if layer.kind != "thematic":  # reopened from the recent list by content
            self.add_recent(path)
        return layer

    def _vector_layer_choice(self, path: str) -> str | None:
        """``path``, or ``path::LAYER`` for a GIS file of several layers (asked with
        `ask_layer`; None when the user cancels)."""
        from globeview.app.layer_dispatch import split_sublayer
        from globeview.model.vector_files import vector_file_layers

        if split_sublayer(path)[1] is not None or self.overlay_host.layer_type_for(path) != "gis":
            return path
        layers = vector_file_layers(path)
        if len(layers) < 2:
            return path
        name = self.ask_layer(self.window, Path(path).name, layers)
        return None if name is None else f"{path}::{name}"

    def open_embedded_overlays(self) -> list[Any]:
        """The embedded overlays: the borders shown, the Blue Marble listed but hidden
        (models through the built-in layer types: no GL). Returns the layers opened."""
        try:
            layers = self.overlay_host.open_embedded(imagery=True)
            for layer in layers:
                if layer.kind in ("imagery", "thematic"):
                    layer.set_visible(False)  # announced: listed and drawn hidden
        except Exception as exc:  # noqa: BLE001  any failure is one line in a dialog, the window keeps working
            self.errors.error(exc, "adding the embedded overlays")
            return []
        return layers

    def open_embedded_overlays_after_first_view(self) -> None:
        """`open_embedded_overlays` once the globe's first complete view is drawn (no tile
        loading), or `EMBEDDED_OVERLAYS_LATEST_MS` after this call at the latest (issue #27:
        the window's launch to the globe drawn; reading and densifying the borders and
        draping them on every new tile cost ~0.2 CPU-s before it). They go below any overlay
        opened meanwhile, as if opened first; a project opened meanwhile replaces them
        (`cancel_embedded_overlays`)."""
        self._embedded_pending = True
        self.globe.frameRendered.connect(self._first_view_drawn)
        timer = QTimer(self.window)  # goes with the window
        timer.setSingleShot(True)
        timer.timeout.connect(self._open_pending_embedded)
        timer.start(EMBEDDED_OVERLAYS_LATEST_MS)

    @property
    def embedded_overlays_pending(self) -> bool:
        """Whether the embedded overlays are still to be opened (after the first view)."""
        return self._embedded_pending

    def cancel_embedded_overlays(self) -> None:
        """Do not open the pending embedded overlays (a project's overlays replace them)."""
        self._embedded_pending = False

    def _first_view_drawn(self, stats: Any, _fps: float) -> None:
        if getattr(stats, "tiles_loading", 0) == 0:
            self._open_pending_embedded()

    def _open_pending_embedded(self) -> None:
        if not self._embedded_pending or not self.window.isVisible():
            return  # a window not shown yet (or closed) opens them at its first view
        self._embedded_pending = False
        self.globe.frameRendered.disconnect(self._first_view_drawn)
        opened = {id(layer) for layer in self.open_embedded_overlays()}
        if opened:
            order = list(self.model.overlays)
            first = [ly for ly in order if id(ly) in opened]
            self.model.set_overlay_order(first + [ly for ly in order if id(ly) not in opened])

    # -- the loader's progress ----------------------------------------------------------------

    def _load_started(self, path: str) -> None:
        self.load_label.setText(f"Opening {source_name(path, stem=False)}…")
        self.load_bar.setRange(0, 0)  # indeterminate until progress arrives
        for w in (self.load_label, self.load_bar, self.cancel_button):
            w.show()

    def _load_progress(self, done: int, total: int) -> None:
        if total > 0:
            self.load_bar.setRange(0, total)
            self.load_bar.setValue(done)

    def _load_idle(self) -> None:
        for w in (self.load_label, self.load_bar, self.cancel_button):
            w.hide()

    def _load_failed(self, path: str, exc: BaseException) -> None:
        self.errors.error(exc, f"cannot open {source_name(path, stem=False)}")

    def _loaded(self, path: str, store: TileStore) -> None:
        try:
            self.add_store(store, source_name(path))
        except Exception as exc:  # noqa: BLE001  any failure is one line in a dialog, the window keeps working
            self.errors.error(exc, f"cannot add {source_name(path, stem=False)}")
            return
        self.add_recent(path)
        if bool(getattr(store, "offline", False)):
            # The server could not be reached; its manifest came from the disk cache.
            self.errors.notify(
                f"{source_name(path, stem=False)}: the server cannot be reached; offline, "
                "showing the tiles cached before"
            )
        self.globe.fly_to_bounds(tuple(store.bounds))

    def add_store(self, store: TileStore, name: str) -> str:
        """Add a store as the top layer under a unique name; returns the name."""
        # A store read over HTTP: the UI thread (frames, picking, tools) only ever uses what
        # is already fetched; a read that would wait raises TileNotReady at once and the store
        # fetches the tile in the background (globeview.terrain.store.http). No-op when local.
        store.forbid_network_on(threading.get_ident())
        taken = {ly.name for ly in self.terrain.layers}
        unique, n = name, 2
        while unique in taken:
            unique, n = f"{name} ({n})", n + 1
        try:
            self.terrain.add(store, unique)
        except GlobeviewError:
            # The stack appends before it validates: take the layer out again.
            if any(ly.name == unique for ly in self.terrain.layers):
                self.terrain.remove(unique)
            raise
        self.layer_panel.select(unique)  # listed by the terrain event
        return unique

    # -- recent files ------------------------------------------------------------------------

    def recent_files(self) -> list[str]:
        val = self.qsettings.value("files/recent")
        if val is None:
            return []
        if isinstance(val, str):
            return [val]
        return [str(v) for v in val]

    def add_recent(self, path: str) -> None:
        """Put a file, folder or store URL first in File > Open Recent (at most `MAX_RECENT`)."""
        p = str(path) if is_store_url(str(path)) else str(Path(path).absolute())
        files = [p] + [f for f in self.recent_files() if f != p]
        self.qsettings.setValue("files/recent", files[:MAX_RECENT])
        self._update_recent_menu()

    def _update_recent_menu(self) -> None:
        self.recent_menu.clear()
        files = self.recent_files()
        for f in files:
            act = self.recent_menu.addAction(f)
            act.triggered.connect(lambda _checked=False, f=f: self.open_paths([f]))
        self.recent_menu.setEnabled(bool(files))


def source_name(path: str, stem: bool = True) -> str:
    """What the window calls an opened source: a file's stem (``name`` with ``stem`` False),
    a store folder's name, or a store URL's last path segment (decoded; the host when the
    path is empty)."""
    if is_store_url(path):
        parts = urllib.parse.urlsplit(path)
        last = urllib.parse.unquote(parts.path.rstrip("/").rsplit("/", 1)[-1])
        return last or parts.hostname or path
    return Path(path).stem if stem else Path(path).name


def classify_path(path: str | Path, registry: Any = None) -> str:
    """'dem' or 'overlay' for a file dropped or opened without saying which: tile store
    folders, DEM-only formats and single-band numeric rasters (what the built-in 'thematic'
    layer type takes) are DEMs; whatever another enabled layer type opens (dispatch by
    extension and content over ``registry``'s layer types, built-in or installed; default:
    the installed plugins) is an overlay. Raises `GlobeviewError` (one line) for anything
    else, naming the installed layer types."""
    p = Path(path)
    if p.is_dir():
        return "dem"
    if not p.exists():
        raise missing_path_error(p)
    if p.suffix.lower() in (".hgt", ".dem", ".bil", ".dt0", ".dt1", ".dt2", ".nc"):
        return "dem"
    if registry is None:
        registry = PluginRegistry().discover()
    kind = choose_layer_type(registry, p)
    return "dem" if kind == "thematic" else "overlay"
