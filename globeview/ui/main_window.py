"""`MainWindow`: the globe view in the middle, the layer and plugin panels as docks, the
menus, the toolbars and the status bar: a thin shell over the Qt-free model
(`globeview.model.Globe`, made here before any GL exists and handed to the session). Widgets
edit the model and subscribe to its events (``globe.events`` and ``globe.display.events``):
a change made anywhere (a control, code, a plugin, the session's fallback) shows in every
widget, and nothing calls a panel's refresh by hand. The window holds no algorithm of its own.

The window puts together parts with one job each, and wires them to the model, the globe
view and one another:

- `ViewToolbar` (ui/view_toolbar.py): the Display toolbar (Go to, exaggeration, wireframe,
  hillshade);
- `FileOpening` (ui/file_opening.py): File > Open DEM… / Open Overlay… / Open URL… / Open
  Recent, drag and drop and the command line's files, the background DEM loader and its
  progress; overlays live in the model (``Globe.overlays``), opened by the window's
  `OverlayHost` with or without GL (the session draws them);
- `WindowTools` (ui/window_tools.py): the Tools toolbar and menu, the tools' declared
  commands and the Tool options bar;
- `ProjectActions` (ui/project_actions.py): File > Open Project… / Save Project… and the
  Bookmarks menu;
- the docks (`LayerPanel`, `PluginPanel`, the Plot dock), the status bar (`StatusBar`) and
  the plugins' window side (`PluginHost`).

What stays here: building the menus from the parts' actions, the status bar's reports of
frames, the LOD provider and the camera, the window's persisted settings (layout, tau,
display, height reference), Export Image, and closing. With ``embedded_overlays`` the window
starts with the Natural Earth borders shown and the Blue Marble drape listed but hidden (the
hypsometric relief is what a person sees first; one tick shows the imagery)."""

from __future__ import annotations

import logging

from PyQt6.QtCore import QSettings, Qt, QTimer
from PyQt6.QtGui import QAction, QCloseEvent, QDragEnterEvent, QDropEvent, QKeySequence
from PyQt6.QtWidgets import QDockWidget, QFileDialog, QFrame, QMainWindow, QScrollArea, QWidget

from globeview.app.overlay_host import OverlayHost
from globeview.errors import GlobeviewError
from globeview.model.camera import Camera
from globeview.model.globe import Globe
from globeview.plugins.registry import PluginRegistry
from globeview.terrain.compose.stack import TerrainStack
from globeview.ui.errors import ErrorReporter, UserMessage
from globeview.ui.file_opening import FileOpening
from globeview.ui.globe_widget import GlobeWidget
from globeview.ui.layer_panel import LayerPanel
from globeview.ui.navigation import HOME_POSE
from globeview.ui.plot_dock import install_plot_dock
from globeview.ui.plugin_host import PluginHost, QSettingsBackend
from globeview.ui.plugin_panel import TAU_MAX_PX, TAU_MIN_PX, PluginPanel
from globeview.ui.project_actions import ProjectActions
from globeview.ui.status import ELLIPSOIDAL, ORTHOMETRIC, StatusBar
from globeview.ui.subscriptions import Subscriptions
from globeview.ui.tour_panel import TourPanel
from globeview.ui.view_toolbar import EXAG_MAX_TENTHS, ViewToolbar
from globeview.ui.window_tools import WindowTools

#: QSettings key of the cursor height reference (`ORTHOMETRIC` or `ELLIPSOIDAL`).
HEIGHT_REFERENCE_KEY = "view/height_reference"

log = logging.getLogger("globeview.ui")


class MainWindow(QMainWindow):
    """The globeview window.

    Args:
        terrain: the DEM layers to show.
        settings: where layout, tau, display toggles, recent files and plugin choices
            persist (tests pass an ini file of their own).
        registry: the plugin registry (default: a new one on ``settings``, discovered).
        show_error: how modal error messages are shown (default: a message box); tests
            inject a recorder so no dialog blocks.
        camera: the initial camera (default: the whole globe).
        embedded_overlays: open the embedded overlays (country borders shown, Blue Marble
            imagery listed but hidden).
        model: the `Globe` to show (its ``terrain`` must be ``terrain``): the window shows
            and edits this very model, e.g. a `globeview.Globe`'s from a script
            (`globeview.show`); its camera, tau and display settings are kept, not
            restored from ``settings``. Default: a new one.
        overlay_host: the `OverlayHost` opening overlays onto ``model`` (default: a new one
            on ``registry``).

    Its parts: ``view_bar`` (`ViewToolbar`), ``files`` (`FileOpening`), ``tools``
    (`WindowTools`), ``layer_panel``, ``plugin_panel``, ``plot_dock``, ``status``,
    ``plugins`` (`PluginHost`), ``globe`` (the `GlobeWidget`) and ``overlay_host``.
    """

    def __init__(
        self,
        terrain: TerrainStack,
        settings: QSettings | None = None,
        registry: PluginRegistry | None = None,
        show_error=None,
        camera: Camera | None = None,
        embedded_overlays: bool = False,
        model: Globe | None = None,
        overlay_host: OverlayHost | None = None,
    ) -> None:
        super().__init__()
        self.setWindowTitle("globeview")
        self.setAcceptDrops(True)
        self.qsettings = settings or QSettings("globeview", "globeview")
        self.terrain = terrain
        self.errors = ErrorReporter(show_error, self)
        #: The globe shown, as data (camera, layers, overlays, LOD provider, tool, tau,
        #: display settings); every widget below shows it and edits it.
        self._own_model = model is None
        if model is None:
            model = Globe(
                terrain,
                camera or Camera.from_lonlat(*HOME_POSE),
                tau_px=_tau_setting(self.qsettings.value("view/tau")),
            )
        elif model.terrain is not terrain:
            raise ValueError("MainWindow: terrain is not the model's terrain")
        elif camera is not None:
            model.camera = camera
        self.model = model
        #: Every model subscription of the window and its children (they are handed this
        #: one): cleared in one go when the window closes.
        self.subscriptions = Subscriptions()

        self.status = StatusBar(self)
        self.setStatusBar(self.status)

        # Plugins
        if registry is None:
            # Interactive: a plugin call overrunning the frame budget again and again would
            # freeze the window, so it is disabled (headless runs only warn).
            registry = PluginRegistry(QSettingsBackend(self.qsettings), budget_policy="disable")
        self.plugins = PluginHost(registry, self.model, self, self.subscriptions)
        self.plugins.notice.connect(self.errors.notify)
        if len(registry) == 0:
            self.plugins.discover()
        else:
            self.plugins.refresh()

        #: Opens overlay files onto the model through the layer types, with or without GL
        #: (the session draws what it opened).
        if overlay_host is not None and (
            overlay_host.globe is not self.model or overlay_host.registry is not registry
        ):
            raise ValueError("MainWindow: overlay_host is not for this model and registry")
        self.overlay_host = overlay_host or OverlayHost(self.model, registry)
        self.globe = GlobeWidget(
            self.model, registry, self, self.subscriptions, overlays=self.overlay_host
        )
        self.setCentralWidget(self.globe)

        # Docks
        self.layer_panel = LayerPanel(self.model, subscriptions=self.subscriptions)
        self.layer_panel.overlays.bind(self.overlay_host)
        self.layer_dock = self._dock("Layers", "layers", self.layer_panel)
        self.plugin_panel = PluginPanel(self.plugins, subscriptions=self.subscriptions)
        # Scrollable: the panel's full height (plugin list, provider settings) must not set
        # the window's minimum height, or the window grows whenever another dock does.
        plugin_scroll = QScrollArea()
        plugin_scroll.setWidgetResizable(True)
        plugin_scroll.setFrameShape(QFrame.Shape.NoFrame)
        plugin_scroll.setWidget(self.plugin_panel)
        self.plugin_dock = self._dock("Plugins", "plugins", plugin_scroll)

        self.files = FileOpening(
            self,
            self.model,
            registry,
            self.overlay_host,
            self.globe,
            self.layer_panel,
            self.status,
            self.errors,
            self.qsettings,
        )
        self.view_bar = ViewToolbar(self, self.model.display, self.globe, self.errors)
        self.addToolBar(self.view_bar)
        self._build_menus()
        self.tools = WindowTools(
            self, self.globe, self.model, self.plugins, self.errors, self.status
        )
        self._connect()
        self._restore()
        self.plot_dock = install_plot_dock(self)  # shows the active tool's plot, if any
        if embedded_overlays:  # after the first complete view (issue #27: the launch)
            self.files.open_embedded_overlays_after_first_view()
        self.globe.setFocus()

    # -- construction ----------------------------------------------------------------------
    def _dock(self, title: str, name: str, widget: QWidget) -> QDockWidget:
        dock = QDockWidget(title, self)
        dock.setObjectName(f"dock-{name}")
        dock.setWidget(widget)
        self.addDockWidget(Qt.DockWidgetArea.LeftDockWidgetArea, dock)
        return dock

    def _tour_dock(self) -> tuple[TourPanel, QDockWidget]:
        """The Tour dock (record, play, export a movie), a tab behind the plugins."""
        registry = self.plugins.registry
        panel = TourPanel(self.model, registry, self.overlay_host, self.errors, self.globe)
        panel.notice.connect(self.status.notice)
        dock = self._dock("Tour", "tour", panel)
        self.tabifyDockWidget(self.plugin_dock, dock)
        self.plugin_dock.raise_()
        return panel, dock

    def _build_menus(self) -> None:
        # The Tour dock first: its Export Movie… and toggle go in File and View.
        self.tour_panel, self.tour_dock = self._tour_dock()
        mb = self.menuBar()
        files = self.files
        file_menu = mb.addMenu("&File")
        file_menu.addAction(files.open_action)
        file_menu.addAction(files.open_overlay_action)
        file_menu.addAction(files.open_url_action)
        file_menu.addMenu(files.recent_menu)
        # Projects and bookmarks (ui/project_actions.py, issue #26 item 4).
        self.projects = ProjectActions(self)
        file_menu.addSeparator()
        file_menu.addAction(self.projects.open_action)
        file_menu.addAction(self.projects.save_action)
        file_menu.addSeparator()
        self.export_action = QAction("&Export Image…", self)
        self.export_action.setShortcut(QKeySequence("Ctrl+E"))
        self.export_action.triggered.connect(self.export_dialog)
        file_menu.addAction(self.export_action)
        self.export_movie_action = QAction("Export &Movie…", self)
        self.export_movie_action.triggered.connect(self.tour_panel.export_dialog)
        file_menu.addAction(self.export_movie_action)
        file_menu.addSeparator()
        quit_action = QAction("&Quit", self)
        quit_action.setShortcut(QKeySequence.StandardKey.Quit)
        quit_action.triggered.connect(self.close)
        file_menu.addAction(quit_action)

        view_menu = mb.addMenu("&View")
        home = QAction("&Whole Globe", self)
        home.setShortcut(QKeySequence("Ctrl+Home"))
        home.triggered.connect(lambda: self.globe.go_home())
        view_menu.addAction(home)
        view_menu.addSeparator()
        view_menu.addAction(self.layer_dock.toggleViewAction())
        view_menu.addAction(self.plugin_dock.toggleViewAction())
        view_menu.addAction(self.tour_dock.toggleViewAction())
        view_menu.addSeparator()
        # Cursor heights above the geoid (m a.s.l., the default) or the ellipsoid (m ell.).
        self.ellipsoidal_action = QAction("&Ellipsoidal Heights (m ell.)", self)
        self.ellipsoidal_action.setCheckable(True)
        self.ellipsoidal_action.setToolTip(
            "Show heights above the WGS84 ellipsoid instead of above the EGM96 geoid (sea level)"
        )
        self.ellipsoidal_action.toggled.connect(self._height_reference_changed)
        view_menu.addAction(self.ellipsoidal_action)
        mb.addMenu(self.projects.bookmarks_menu)

    def _height_reference_changed(self, ellipsoidal: bool) -> None:
        reference = ELLIPSOIDAL if ellipsoidal else ORTHOMETRIC
        self.status.set_height_reference(reference)
        self.qsettings.setValue(HEIGHT_REFERENCE_KEY, reference)

    def _connect(self) -> None:
        g = self.globe
        tools = self.tools
        g.sceneReady.connect(self.plugins.bind)
        g.frameRendered.connect(self.status.show_frame)
        g.frameRendered.connect(self._show_fallback_reason)  # after show_frame: on top of it
        g.frameRendered.connect(self._frame_drawn)
        g.cursorPicked.connect(self.status.show_pick)
        g.renderFailed.connect(lambda exc: self.errors.notify(f"drawing failed: {exc}"))
        self.errors.notified.connect(self.status.notice)
        self.layer_panel.zoomRequested.connect(g.fly_to_bounds)
        self.plugins.lodChanged.connect(self._use_lod)
        self.plugins.redrawRequested.connect(g.request_frame)
        self.plugins.statusText.connect(self.status.notice)  # a plugin's set_status: no warning
        self.plugins.changed.connect(tools.refresh)
        g.sceneReady.connect(lambda _s: tools.refresh())
        g.keyUnhandled.connect(tools.key_unhandled)
        # The model's events: whoever changed it, the window shows it.
        events, subs = self.model.events, self.subscriptions
        subs.connect(events.camera, self._camera_changed)
        subs.connect(events.tau_px, self._tau_changed)
        subs.connect(events.tool, tools.model_tool_changed)
        subs.connect(self.model.display.events.all, self.view_bar.show_display)
        self._camera_changed()  # the altitude from the start, then on every camera event

    def _restore(self) -> None:
        s = self.qsettings
        geom = s.value("window/geometry")
        if geom is not None:
            self.restoreGeometry(geom)
        else:
            self.resize(1280, 800)
        state = s.value("window/state")
        if state is not None:
            self.restoreState(state)
        if self._own_model:  # a model handed in keeps its own display settings
            self._restore_display(s)
        self.view_bar.show_display()
        self.ellipsoidal_action.setChecked(s.value(HEIGHT_REFERENCE_KEY) == ELLIPSOIDAL)

    def _restore_display(self, s: QSettings) -> None:
        display = self.model.display
        display.exaggeration = _exaggeration_setting(s.value("view/exaggeration"))
        display.wireframe = _bool(s.value("view/wireframe"), False)
        display.hillshade = _bool(s.value("view/hillshade"), False)

    def save_settings(self) -> None:
        s = self.qsettings
        s.setValue("window/geometry", self.saveGeometry())
        s.setValue("window/state", self.saveState())
        s.setValue("view/tau", self.model.tau_px)
        s.setValue("view/exaggeration", self.model.display.exaggeration)
        s.setValue("view/wireframe", self.model.display.wireframe)
        s.setValue("view/hillshade", self.model.display.hillshade)
        s.setValue(HEIGHT_REFERENCE_KEY, self.status.height_reference)
        s.sync()

    # -- the status bar and the window's settings ------------------------------------------
    def _camera_changed(self, *_args: object) -> None:
        self.status.show_altitude(self.model.camera.height)

    def _tau_changed(self, *_args: object) -> None:
        self.qsettings.setValue("view/tau", self.model.tau_px)

    def _frame_drawn(self, *_args: object) -> None:
        self.tools.frame_drawn()  # a frame was drawn with the tool: it is active
        self.plugins.after_frame()
        scene = self.globe.scene
        # An overlay the GPU side refused (its limits) was dropped at this frame: say so in
        # one line, after the frame (no dialog inside paintGL).
        for line in [] if scene is None else scene.take_overlay_errors():
            QTimer.singleShot(0, lambda line=line: self.errors.error(GlobeviewError(line)))

    def _use_lod(self, name: str) -> None:
        self.status.lod.setText(f"LOD {name}")
        self._show_fallback_reason()

    def _show_fallback_reason(self, *_args: object) -> None:
        """After a fallback the LOD field's tooltip starts with the real reason (notices pass;
        this stays until the user picks a provider again), above what the frame put there."""
        why = self.plugins.fallback_reason
        tip = self.status.lod.toolTip()
        if why and not tip.startswith(why):
            self.status.lod.setToolTip(f"{why}\n{tip}" if tip else why)

    # -- the model's overlays ----------------------------------------------------------------
    def overlay_layers(self) -> list:
        """The model's overlay layers, bottom first."""
        return list(self.model.overlays)

    # -- export ------------------------------------------------------------------------------
    def export_dialog(self) -> None:
        path, _ = QFileDialog.getSaveFileName(self, "Export Image", "globe.png", "PNG (*.png)")
        if path:
            self.export_image(path)

    def export_image(self, path: str) -> bool:
        """Write the current frame to a PNG; a failure is reported, not raised."""
        image = self.globe.grab_image()
        if image.isNull() or not image.save(path, "PNG"):
            self.errors.error(GlobeviewError(f"cannot write the image {path}"))
            return False
        self.status.notice(f"wrote {path}")
        return True

    # -- drag and drop -----------------------------------------------------------------------
    def dragEnterEvent(self, event: QDragEnterEvent) -> None:
        if event.mimeData().hasUrls():
            event.acceptProposedAction()

    def dropEvent(self, event: QDropEvent) -> None:
        paths = [
            u.toLocalFile() if u.isLocalFile() else u.toString()
            for u in event.mimeData().urls()
            if u.isLocalFile() or u.scheme() in ("http", "https")  # a link to a store
        ]
        if paths:
            event.acceptProposedAction()
            self.files.open_paths(paths)

    # -- shutdown ----------------------------------------------------------------------------
    def closeEvent(self, event: QCloseEvent) -> None:
        self.save_settings()
        self.globe.flight.stop()
        self.tour_panel.stop()
        self.files.loader.shutdown()
        self.globe.release_gl()
        # Nothing may keep the released session (and its terrain caches) alive, and the
        # model (it may outlive the window) must not call the closed widgets.
        self.plugins.unbind()
        self.layer_panel.overlays.bind(None)
        self.subscriptions.clear()  # the children's too: they were handed this one
        super().closeEvent(event)

    def last_error(self) -> UserMessage | None:
        return self.errors.history[-1] if self.errors.history else None


def _tau_setting(value: object) -> float:
    """The saved tau (pixels) if it is one the tau slider shows, else the default 2 px (a
    hand-edited or foreign settings file must not stop the window from opening)."""
    tau = _float(value, 2.0)
    return tau if TAU_MIN_PX <= tau <= TAU_MAX_PX else 2.0


def _exaggeration_setting(value: object) -> float:
    """The saved exaggeration if the slider shows it (0.1x .. 50x), else 1."""
    exag = _float(value, 1.0)
    return exag if 0.1 <= exag <= EXAG_MAX_TENTHS / 10.0 else 1.0


def _float(value: object, default: float) -> float:
    try:
        return float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return default


def _bool(value: object, default: bool) -> bool:
    if value is None:
        return default
    if isinstance(value, str):
        return value.lower() in ("1", "true", "yes")
    return bool(value)
