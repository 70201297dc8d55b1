"""`MainWindow`: the globe view in the middle, the layer and plugin panels as docks, the
display and tools toolbars, menus, and the status bar: a thin shell over the Qt-free model
(`globeview.model.Globe`, made here before any GL exists and handed to the session). Widgets
edit the model and subscribe to its events (``globe.events`` and ``globe.display.events``):
a change made anywhere (a control, code, a plugin, the session's fallback) shows in every
widget, and nothing calls a panel's refresh by hand. The window holds no algorithm of its own.

The Tools toolbar and menu list the enabled tool plugins (rebuilt when plugins are enabled or
disabled) as checkable actions, at most one active. Everything else a tool shows is built from
what it declares, the same for built-in and installed tools (no tool-specific code here): its
`Setting`s become controls in the "Tool options" bar while it is active (changes persist
through the registry like provider settings), and its manifest commands
(``[[contributions.commands]]``) become actions — Tools menu entries, buttons in that bar and
keyboard shortcuts — that activate the tool and call the declared method (`tool_options`).

Overlays (imagery, thematic rasters, vectors, points) live in the session
(``GlobeSession.overlay_layers``) and are listed in the layer panel's "Overlays" group. File >
Open Overlay… opens any raster or GeoJSON as an overlay (a single-band raster becomes a
thematic drape); File > Open DEM… opens terrain; File > Open URL… opens a tile store served over
HTTP (remembered in Open Recent like files; its tiles stream in, those that fail stay stood in
by coarser ones and are counted in the status bar); drag and drop, recent files and the command
line decide by content (`classify_path`): GeoJSON and RGB(A)/paletted rasters are overlays,
single-band numeric rasters and tile store folders are DEMs. With ``embedded_overlays`` the
window starts with the Natural Earth borders shown and the Blue Marble drape listed but
hidden (the hypsometric relief is what a person sees first; one tick shows the imagery)."""

from __future__ import annotations

import logging
import math
import threading
from pathlib import Path
from typing import Any

from PyQt6.QtCore import QKeyCombination, QSettings, Qt, QTimer
from PyQt6.QtGui import (
    QAction,
    QActionGroup,
    QCloseEvent,
    QDragEnterEvent,
    QDropEvent,
    QKeySequence,
)
from PyQt6.QtWidgets import (
    QCheckBox,
    QDockWidget,
    QFileDialog,
    QFrame,
    QLabel,
    QLineEdit,
    QMainWindow,
    QProgressBar,
    QPushButton,
    QScrollArea,
    QSlider,
    QToolBar,
    QWidget,
)

from globeview.errors import GlobeviewError
from globeview.model.camera import Camera, camera_for_bounds
from globeview.model.globe import Globe
from globeview.plugins.registry import PluginRegistry
from globeview.terrain.compose.stack import TerrainStack
from globeview.terrain.sources import check_store_url, is_store_url
from globeview.terrain.store.tile_store import TileStore
from globeview.ui.errors import ErrorReporter, UserMessage
from globeview.ui.globe_widget import GlobeWidget
from globeview.ui.layer_panel import LayerPanel
from globeview.ui.loading import DemLoader, missing_path_error
from globeview.ui.navigation import HOME_POSE
from globeview.ui.open_url import ask_store_url
from globeview.ui.plot_dock import install_plot_dock
from globeview.ui.plugin_host import PluginHost, QSettingsBackend
from globeview.ui.plugin_panel import TAU_MAX_PX, TAU_MIN_PX, PluginPanel
from globeview.ui.status import ELLIPSOIDAL, ORTHOMETRIC, StatusBar
from globeview.ui.subscriptions import Subscriptions
from globeview.ui.tool_options import (
    CommandSpec,
    ToolOptionsBar,
    portable,
    reserved_shortcuts,
    shortcut_clash,
)

#: QSettings key of the cursor height reference (`ORTHOMETRIC` or `ELLIPSOIDAL`).
HEIGHT_REFERENCE_KEY = "view/height_reference"

log = logging.getLogger("globeview.ui")

#: Seconds the Go to flight takes. Issue #17 asks for a complete view <= 1 s after Go to: a
#: 1 s flight (the other flights' length) alone used all of it; the destination's tiles load
#: while it flies (`GlobeWidget.prefetch_pose`), so a short flight is what makes it possible.
GOTO_FLIGHT_S = 0.5

MAX_RECENT = 10
DEM_FILTER = (
    "DEM rasters (*.tif *.tiff *.hgt *.dem *.asc *.img *.vrt *.nc *.bil *.dt0 *.dt1 *.dt2);;"
    "All files (*)"
)
#: The embedded Blue Marble drape's layer name (listed, hidden at start).
BLUE_MARBLE = "bluemarble_2048x1024.tif"
#: Exaggeration slider: tenths, 0.1x .. 50x.
EXAG_MAX_TENTHS = 500


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
        embedded_overlays: add the embedded overlays once the globe is up (country borders
            shown, Blue Marble imagery listed but hidden).
    """

    def __init__(
        self,
        terrain: TerrainStack,
        settings: QSettings | None = None,
        registry: PluginRegistry | None = None,
        show_error=None,
        camera: Camera | None = None,
        embedded_overlays: bool = False,
    ) -> None:
        super().__init__()
        self._embedded_overlays = embedded_overlays
        #: The tool asked for by `set_tool` until a frame is drawn with it (its activation
        #: can fail until then).
        self._activating: str | None = None
        self._showing_display = False
        #: Overlay files asked for before the globe's GL (and session) existed.
        self._pending_overlays: list[str] = []
        self.setWindowTitle("globeview")
        self.setAcceptDrops(True)
        self.qsettings = settings or QSettings("globeview", "globeview")
        self.terrain = terrain
        self.errors = ErrorReporter(show_error, self)
        #: How File > Open URL… asks for the URL: ``ask_url(parent, initial) -> str | None``
        #: (the checked URL or None when cancelled); tests put a function of their own here.
        self.ask_url = ask_store_url
        #: The globe shown, as data (camera, layers, overlays, LOD provider, tool, tau,
        #: display settings); every widget below shows it and edits it.
        self.model = Globe(
            terrain,
            camera or Camera.from_lonlat(*HOME_POSE),
            tau_px=_tau_setting(self.qsettings.value("view/tau")),
        )
        #: Every model subscription of the window and its children (they are handed this
        #: one): cleared in one go when the window closes.
        self.subscriptions = Subscriptions()

        self.status = StatusBar(self)
        self.setStatusBar(self.status)
        self.load_bar = QProgressBar()
        self.load_bar.setMaximumWidth(160)
        self.load_label = QLabel()
        self.cancel_button = QPushButton("Cancel")
        self.cancel_button.setToolTip("Cancel opening the DEM")
        for w in (self.load_label, self.load_bar, self.cancel_button):
            self.status.addWidget(w)
            w.hide()

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

        self.globe = GlobeWidget(self.model, registry, self, self.subscriptions)
        self.setCentralWidget(self.globe)

        # Docks
        self.layer_panel = LayerPanel(self.model, subscriptions=self.subscriptions)
        self.layer_dock = self._dock("Layers", "layers", self.layer_panel)
        self.plugin_panel = PluginPanel(self.plugins, subscriptions=self.subscriptions)
        # Scrollable: the panel's full height (plugin list, provider settings) must not set
        # the window's minimum height, or the window grows whenever another dock does.
        plugin_scroll = QScrollArea()
        plugin_scroll.setWidgetResizable(True)
        plugin_scroll.setFrameShape(QFrame.Shape.NoFrame)
        plugin_scroll.setWidget(self.plugin_panel)
        self.plugin_dock = self._dock("Plugins", "plugins", plugin_scroll)

        self.loader = DemLoader(self)
        self._build_toolbar()
        self._build_menus()
        self._build_tools()
        self._connect()
        self._restore()
        self.plot_dock = install_plot_dock(self)  # shows the active tool's plot, if any
        self.globe.setFocus()

    # -- construction ----------------------------------------------------------------------
    def _dock(self, title: str, name: str, widget: QWidget) -> QDockWidget:
        dock = QDockWidget(title, self)
        dock.setObjectName(f"dock-{name}")
        dock.setWidget(widget)
        self.addDockWidget(Qt.DockWidgetArea.LeftDockWidgetArea, dock)
        return dock

    def _build_toolbar(self) -> None:
        tb = QToolBar("Display", self)
        tb.setObjectName("toolbar-display")
        self.addToolBar(tb)
        tb.addWidget(QLabel(" Go to "))
        self.goto_edit = QLineEdit()
        self.goto_edit.setPlaceholderText("lon, lat[, height m[, heading, pitch]]")
        self.goto_edit.setToolTip(
            "Fly to a place: longitude and latitude in degrees, optionally a height in metres "
            "and a heading and pitch in degrees (default: looking straight down)"
        )
        self.goto_edit.setMaximumWidth(220)
        self.goto_edit.returnPressed.connect(lambda: self.go_to(self.goto_edit.text()))
        tb.addWidget(self.goto_edit)
        tb.addSeparator()
        tb.addWidget(QLabel(" Exaggeration "))
        self.exag_slider = QSlider(Qt.Orientation.Horizontal)
        self.exag_slider.setRange(1, EXAG_MAX_TENTHS)
        self.exag_slider.setMaximumWidth(160)
        self.exag_slider.setToolTip("Vertical exaggeration of the terrain (1x = true relief)")
        self.exag_label = QLabel()
        tb.addWidget(self.exag_slider)
        tb.addWidget(self.exag_label)
        tb.addSeparator()
        self.wire_check = QCheckBox("Wireframe")
        self.wire_check.setToolTip("Overlay the triangle edges")
        self.hill_check = QCheckBox("Hillshade")
        self.hill_check.setToolTip("Shade relief with a light from the north-west")
        tb.addWidget(self.wire_check)
        tb.addWidget(self.hill_check)

    def _build_menus(self) -> None:
        mb = self.menuBar()
        file_menu = mb.addMenu("&File")
        self.open_action = QAction("&Open DEM…", self)
        self.open_action.setShortcut(QKeySequence.StandardKey.Open)
        self.open_action.triggered.connect(self.open_dialog)
        file_menu.addAction(self.open_action)
        self.open_overlay_action = QAction("Open &Overlay…", self)
        self.open_overlay_action.setShortcut(QKeySequence("Ctrl+Shift+O"))
        self.open_overlay_action.setToolTip(
            "Drape imagery or a thematic raster, or show GeoJSON lines or points"
        )
        self.open_overlay_action.triggered.connect(self.open_overlay_dialog)
        file_menu.addAction(self.open_overlay_action)
        self.open_url_action = QAction("Open &URL…", self)
        self.open_url_action.setShortcut(QKeySequence("Ctrl+U"))
        self.open_url_action.setToolTip(
            "Open a tile store served over HTTP(S) by its URL (tiles stream in as needed)"
        )
        self.open_url_action.triggered.connect(self.open_url_dialog)
        file_menu.addAction(self.open_url_action)
        self.recent_menu = file_menu.addMenu("Open &Recent")
        self.export_action = QAction("&Export Image…", self)
        self.export_action.setShortcut(QKeySequence("Ctrl+E"))
        self.export_action.triggered.connect(self.export_dialog)
        file_menu.addAction(self.export_action)
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
        view_menu.addSeparator()
        # Cursor heights above the geoid (m a.s.l., the default) or the ellipsoid (m ell.).
        self.ellipsoidal_action = QAction("&Ellipsoidal Heights (m ell.)", self)
        self.ellipsoidal_action.setCheckable(True)
        self.ellipsoidal_action.setToolTip(
            "Show heights above the WGS84 ellipsoid instead of above the EGM96 geoid (sea level)"
        )
        self.ellipsoidal_action.toggled.connect(self._height_reference_changed)
        view_menu.addAction(self.ellipsoidal_action)
        self._update_recent_menu()

    def _height_reference_changed(self, ellipsoidal: bool) -> None:
        reference = ELLIPSOIDAL if ellipsoidal else ORTHOMETRIC
        self.status.set_height_reference(reference)
        self.qsettings.setValue(HEIGHT_REFERENCE_KEY, reference)

    def _build_tools(self) -> None:
        """The Tools toolbar and menu (actions filled by `refresh_tools`) and the Tool options
        bar (the active tool's settings and command buttons)."""
        self.tools_toolbar = QToolBar("Tools", self)
        self.tools_toolbar.setObjectName("toolbar-tools")
        self.addToolBar(self.tools_toolbar)
        self.tools_menu = self.menuBar().addMenu("&Tools")
        self.tool_group = QActionGroup(self)
        self.tool_group.setExclusionPolicy(QActionGroup.ExclusionPolicy.ExclusiveOptional)
        self.tool_actions: dict[str, QAction] = {}
        #: "tool.command" -> the command's action (menu entry, button, shortcut).
        self.command_actions: dict[str, QAction] = {}
        self._command_specs: list[CommandSpec] = []
        self.tool_options = ToolOptionsBar(self)
        # A row of its own: the settings and buttons of any tool fit without overflowing
        # into the toolbar's extension menu.
        self.addToolBarBreak()
        self.addToolBar(self.tool_options)
        self.tool_options.settingEdited.connect(self._tool_setting_edited)
        self.refresh_tools()

    # -- tools -----------------------------------------------------------------------------
    def tool_labels(self) -> dict[str, str]:
        """Name -> label of the enabled tool plugins' tools (loading them; a plugin that fails
        to load is disabled and reported)."""
        try:
            return {c.name: c.label or c.name for c in self.plugins.registry.contributions("tool")}
        except Exception as exc:
            log.exception("loading tools failed")
            self.errors.notify(f"loading tools failed: {exc}")
            return {}

    def tool_commands(self) -> list[CommandSpec]:
        """The commands the enabled tools declare in their manifests (the plugin whose tool
        the registry uses for each name)."""
        try:
            loaded = self.plugins.registry.contributions("tool")
        except Exception:  # noqa: BLE001  reported by tool_labels
            return []
        specs: list[CommandSpec] = []
        for lc in loaded:
            manifest = self.plugins.registry.get(lc.plugin).manifest
            if manifest is None:
                continue
            for cmd in manifest.contribution(lc.name).commands:
                specs.append(CommandSpec(lc.plugin, lc.name, cmd))
        return specs

    def refresh_tools(self) -> None:
        """Rebuild the tool and command actions from the enabled tool plugins."""
        labels = self.tool_labels()
        specs = self.tool_commands()
        if set(labels) != set(self.tool_actions) or specs != self._command_specs:
            self._remove_tool_actions()
            first = self.tools_toolbar.actions()[0] if self.tools_toolbar.actions() else None
            for name, label in labels.items():
                act = QAction(label, self)
                act.setCheckable(True)
                act.setObjectName(f"tool-{name}")
                act.triggered.connect(lambda checked, n=name: self.set_tool(n if checked else None))
                self.tool_group.addAction(act)
                self.tools_toolbar.insertAction(first, act)
                self.tools_menu.addAction(act)
                self.tool_actions[name] = act
            self._command_specs = specs
            self._build_command_actions(specs)
            for name, label in labels.items():
                keys = [
                    f"{a.shortcut().toString()}: {a.text()}"
                    for k, a in self.command_actions.items()
                    if k.startswith(f"{name}.") and not a.shortcut().isEmpty()
                ]
                tip = label + (f" ({', '.join(keys)})" if keys else "")
                self.tool_actions[name].setToolTip(tip + "; Escape leaves the tool")
        self.tools_menu.setEnabled(bool(self.tool_actions))
        self._sync_tools()

    def _remove_tool_actions(self) -> None:
        self.tool_options.show_tool(None)
        for act in self.tool_actions.values():
            self.tool_group.removeAction(act)
            self.tools_toolbar.removeAction(act)
            self.tools_menu.removeAction(act)
            act.deleteLater()
        for act in self.command_actions.values():
            self.tools_menu.removeAction(act)
            self.removeAction(act)
            act.setShortcut(QKeySequence())  # it lingers until deleted: free its key now
            act.deleteLater()
        if getattr(self, "_commands_separator", None) is not None:
            self.tools_menu.removeAction(self._commands_separator)
            self._commands_separator = None
        self.tool_actions = {}
        self.command_actions = {}

    def _build_command_actions(self, specs: list[CommandSpec]) -> None:
        """One action per declared command: in the Tools menu, on the window (so its shortcut
        works with any tool, or none, active) and as a button in the Tool options bar while
        its tool is active. A shortcut another action or the navigation already uses is
        dropped with a one-line notice; the command keeps working from its button."""
        plugin_actions = set(self.tool_actions.values())
        taken = reserved_shortcuts(
            a for a in self.findChildren(QAction) if a not in plugin_actions and a.isVisible()
        )
        tools = self.plugins.registry.tools() if specs else {}
        self._commands_separator = self.tools_menu.addSeparator() if specs else None
        for spec in specs:
            cmd = spec.command
            tool = tools.get(spec.tool)
            if not callable(getattr(tool, cmd.method, None)):
                self._warn_command(
                    spec, f"names no method {cmd.method}() of the tool; command left out"
                )
                continue
            act = QAction(cmd.label, self)
            act.setObjectName(f"command-{spec.key}")
            tip = f"{cmd.label} ({self.tool_actions[spec.tool].text()})"
            if cmd.shortcut:
                owner = shortcut_clash(cmd.shortcut, taken)
                if owner is None:
                    act.setShortcut(QKeySequence(cmd.shortcut))
                    taken[portable(cmd.shortcut)] = f"command {spec.key}"
                    tip += f" [{cmd.shortcut}]"
                else:
                    self._warn_command(
                        spec, f"shortcut {cmd.shortcut} is taken by {owner}; left without it"
                    )
            act.setToolTip(tip)
            act.triggered.connect(lambda _checked=False, sp=spec: self.run_command(sp.key))
            self.addAction(act)  # the shortcut works whichever tool is active
            self.tools_menu.addAction(act)
            self.command_actions[spec.key] = act

    def _warn_command(self, spec: CommandSpec, what: str) -> None:
        text = f"plugin {spec.plugin}: command {spec.key} {what}"
        log.warning("%s", text)
        self.errors.notify(text)

    def run_command(self, key: str) -> bool:
        """Run command ``"tool.command"``: activate its tool if needed, then call the declared
        method (isolated: a method that raises fails that tool's contribution, reported; a
        `GlobeviewError` is the user's one-line message). Returns whether it ran."""
        spec = next((sp for sp in self._command_specs if sp.key == key), None)
        if spec is None:
            return False
        if self.active_tool_name() != spec.tool and not self.set_tool(spec.tool):
            return False
        tool = self.globe.active_tool()
        if tool is None:
            return False
        try:
            self.plugins.registry.invoke(tool, spec.command.method, user_errors=True)
        except GlobeviewError as exc:
            self.errors.notify(f"{spec.key}: {exc}")
        self.plugins.after_frame()
        self._sync_tools()
        self.globe.request_frame()
        return True

    def _tool_setting_edited(self, name: str, value: object) -> None:
        """A control of the Tool options bar changed: configure the active tool (persisted
        by the registry, like provider settings) and redraw."""
        tool = self.globe.active_tool()
        if tool is None:
            return
        values = dict(getattr(tool, "values", {}) or {})
        values[name] = value
        self.plugins.registry.configure(tool, values)
        self.plugins.after_frame()
        self._sync_tools()
        self.globe.request_frame()

    def active_tool_name(self) -> str | None:
        """The model's active tool, or None."""
        if self.globe.scene is None:
            return None
        return self.model.tool if self.globe.active_tool() is not None else None

    def set_tool(self, name: str | None) -> bool:
        """Activate a tool (None: none); returns whether it is the model's tool now. The
        toolbar, menu and options bar follow the model's ``tool`` event; a tool that fails
        to activate is reported there (`_tool_changed`)."""
        self._activating = name
        ok = self.globe.set_tool(name)
        if not ok and name is not None and self._activating == name:
            # Not reported by the event (e.g. the model's tool never changed).
            self._report_activation_failure(name)
        elif ok and name is not None:
            tool = self.globe.active_tool()
            label = getattr(tool, "label", name) or name
            self.status.notice(f"{label}: on (a drag still moves the globe; Escape leaves)")
        return ok

    def _tool_changed(self, *_args: object) -> None:
        """The model's tool changed (a toolbar click, a command, code, Escape, or its plugin
        failed): check its action and show its options. A tool asked for here that the model
        drops before a frame was drawn with it failed to activate: say why."""
        wanted = self._activating
        if self.model.tool is None and wanted is not None:
            self._report_activation_failure(wanted)
        self._sync_tools()

    def _report_activation_failure(self, name: str) -> None:
        self._activating = None
        why = self.plugins.failure_reason("tool", name)
        if not why and self.plugins.registry.find("tool", name) is not None:
            return  # deactivated, not failed
        self.errors.notify(f"tool {name} could not be activated" + (f": {why}" if why else ""))
        self.plugins.reported("tool", name)  # one line: refresh does not repeat the failure
        self.plugins.refresh()

    def _sync_tools(self, *_args: object) -> None:
        """Check the active tool's action; show its settings and commands (or hide them)."""
        active = self.active_tool_name()
        for name, act in self.tool_actions.items():
            act.blockSignals(True)
            act.setChecked(name == active)
            act.blockSignals(False)
        tool = self.globe.active_tool() if active is not None else None
        act = self.tool_actions.get(active or "")
        commands = [
            a for k, a in self.command_actions.items() if active and k.startswith(f"{active}.")
        ]
        self.tool_options.show_tool(active, tool, act.text() if act else "", commands)

    def _key_unhandled(self, key: int, modifiers: object) -> None:
        """A key the active tool and navigation left: try the tool actions' shortcuts."""
        try:
            seq = QKeySequence(QKeyCombination(Qt.KeyboardModifier(modifiers), Qt.Key(key)))
        except (TypeError, ValueError):
            return
        for act in [*self.tool_actions.values(), *self.command_actions.values()]:
            if not act.shortcut().isEmpty() and act.shortcut().matches(seq) == (
                QKeySequence.SequenceMatch.ExactMatch
            ):
                act.trigger()
                return

    def _connect(self) -> None:
        g = self.globe
        g.sceneReady.connect(self.plugins.bind)
        g.sceneReady.connect(self._scene_ready)
        g.frameRendered.connect(self.status.show_frame)
        g.frameRendered.connect(self._show_fallback_reason)  # after show_frame: on top of it
        g.frameRendered.connect(self._frame_drawn)
        g.cursorPicked.connect(self.status.show_pick)
        g.renderFailed.connect(lambda exc: self.errors.notify(f"drawing failed: {exc}"))
        self.errors.notified.connect(self.status.notice)
        self.layer_panel.zoomRequested.connect(self.zoom_to_bounds)
        self.plugins.lodChanged.connect(self._use_lod)
        self.plugins.redrawRequested.connect(g.request_frame)
        self.plugins.statusText.connect(self.status.notice)  # a plugin's set_status: no warning
        self.plugins.changed.connect(self.refresh_tools)
        g.sceneReady.connect(lambda _s: self.refresh_tools())
        g.keyUnhandled.connect(self._key_unhandled)
        self.exag_slider.valueChanged.connect(self._exaggeration_changed)
        self.wire_check.toggled.connect(self._wireframe_changed)
        self.hill_check.toggled.connect(self._hillshade_changed)
        # The model's events: whoever changed it, the window shows it.
        events, subs = self.model.events, self.subscriptions
        subs.connect(events.camera, self._camera_changed)
        subs.connect(events.tau_px, self._tau_changed)
        subs.connect(events.tool, self._tool_changed)
        subs.connect(self.model.display.events.all, self._show_display)
        self._camera_changed()  # the altitude from the start, then on every camera event
        self.loader.started.connect(self._load_started)
        self.loader.progress.connect(self._load_progress)
        self.loader.loaded.connect(self._loaded)
        self.loader.failed.connect(self._load_failed)
        self.loader.cancelled.connect(
            lambda p: self.errors.notify(f"opening {Path(p).name} cancelled")
        )
        self.loader.idle.connect(self._load_idle)
        self.cancel_button.clicked.connect(self.loader.cancel)

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
        display = self.model.display
        display.exaggeration = _exaggeration_setting(s.value("view/exaggeration"))
        display.wireframe = _bool(s.value("view/wireframe"), False)
        display.hillshade = _bool(s.value("view/hillshade"), False)
        self._show_display()
        self.ellipsoidal_action.setChecked(s.value(HEIGHT_REFERENCE_KEY) == ELLIPSOIDAL)

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

    # -- display ---------------------------------------------------------------------------
    def _camera_changed(self, *_args: object) -> None:
        self.status.show_altitude(self.model.camera.height)

    def _tau_changed(self, *_args: object) -> None:
        self.qsettings.setValue("view/tau", self.model.tau_px)

    def _frame_drawn(self, *_args: object) -> None:
        self._activating = None  # a frame was drawn with the tool: it is active
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

    def _exaggeration_changed(self, tenths: int) -> None:
        if not self._showing_display:
            self.model.display.exaggeration = tenths / 10.0

    def _wireframe_changed(self, on: bool) -> None:
        if not self._showing_display:
            self.model.display.wireframe = bool(on)

    def _hillshade_changed(self, on: bool) -> None:
        if not self._showing_display:
            self.model.display.hillshade = bool(on)

    def _show_display(self, *_args: object) -> None:
        """Show the model's display settings in the toolbar (set here, from code or a
        plugin); the label gives the exaggeration exactly, the slider as near as its range
        allows. Moving the controls to show it does not set the model again."""
        d = self.model.display
        self._showing_display = True
        try:
            exag = float(d.exaggeration)
            if math.isfinite(exag):
                self.exag_slider.setValue(round(min(max(exag * 10, 1), EXAG_MAX_TENTHS)))
            self.exag_label.setText(f"{exag:.1f}×")
            self.wire_check.setChecked(bool(d.wireframe))
            self.hill_check.setChecked(bool(d.hillshade))
        finally:
            self._showing_display = False

    def go_to(self, text: str) -> bool:
        """Fly to ``"lon, lat[, height[, heading, pitch]]"`` (degrees, metres; default
        looking straight down); a bad entry is a notice."""
        try:
            vals = [float(v) for v in text.replace(";", ",").split(",") if v.strip()]
            if len(vals) not in (2, 3, 5) or not all(math.isfinite(v) for v in vals):
                raise ValueError
        except ValueError:
            self.errors.notify(
                "go to: expected 'lon, lat', 'lon, lat, height' or "
                f"'lon, lat, height, heading, pitch', not {text!r}"
            )
            return False
        lon, lat = vals[0], vals[1]
        if not (-180.0 <= lon <= 360.0 and -90.0 <= lat <= 90.0):
            self.errors.notify(f"go to: {lon}, {lat} is not a longitude, latitude in degrees")
            return False
        height = vals[2] if len(vals) >= 3 else min(self.globe.camera.height, 2.0e6)
        heading, pitch = (vals[3], vals[4]) if len(vals) == 5 else (0.0, -90.0)
        pose = (lon, lat, max(height, 10.0), heading % 360.0, pitch)
        try:  # the camera's own checks (height range, pitch), before the flight starts
            Camera.from_lonlat(*pose)
        except ValueError as exc:
            self.errors.notify(f"go to: {exc}")
            return False
        self.globe.flight.fly_to(pose, GOTO_FLIGHT_S)
        return True

    def zoom_to_bounds(self, bounds: tuple[float, float, float, float]) -> None:
        """Fly over a lon/lat box (west, south, east, north degrees)."""
        self.globe.fly_to_camera(camera_for_bounds(*bounds, fovy_deg=self.globe.camera.fovy_deg))

    # -- opening data ------------------------------------------------------------------------
    def open_dialog(self) -> None:
        start = str(Path(self.recent_files()[0]).parent) if self.recent_files() else ""
        paths, _ = QFileDialog.getOpenFileNames(self, "Open DEM", start, DEM_FILTER)
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
                kind = classify_path(p, self.plugins.registry)
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
        url = self.ask_url(self, last)
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
        from globeview.plugins.layer_dispatch import overlay_file_filter

        start = str(Path(self.recent_files()[0]).parent) if self.recent_files() else ""
        name_filter = overlay_file_filter(self.plugins.registry)
        paths, _ = QFileDialog.getOpenFileNames(self, "Open Overlay", start, name_filter)
        self.open_overlays(paths)

    def open_overlays(self, paths: list[str] | tuple[str, ...]) -> list:
        """Open files as overlays (the Open Overlay dialog's path); returns the layers added."""
        layers = [self.open_overlay(str(p)) for p in paths if p]
        return [ly for ly in layers if ly is not None]

    def open_overlay(self, path: str) -> Any:
        """Add a raster or GeoJSON file as an overlay layer (its type decided by content) on
        top of the overlays; a bad file reports its one-line error and changes nothing.
        Returns the layer (None on error, or while the globe is not up yet: then it is added
        once it is)."""
        scene = self.globe.scene
        if scene is None:
            self._pending_overlays.append(str(path))
            return None
        try:
            # No GL here: the layer's GPU side is made at the next frame.
            layer = scene.add_overlay(str(path))  # listed by the model's event
        except Exception as exc:  # noqa: BLE001  any failure is one line in a dialog, the window keeps working
            self.errors.error(exc, "" if isinstance(exc, GlobeviewError) else "opening overlay")
            return None
        self.layer_panel.overlays.select(layer)
        self.status.notice(f"added {layer.kind} overlay {layer.name}")
        if layer.kind != "thematic":  # reopened from the recent list by content
            self.add_recent(path)
        return layer

    def overlay_layers(self) -> list:
        """The model's overlay layers, bottom first."""
        return list(self.model.overlays)

    def _scene_ready(self, scene: Any) -> None:
        """The session exists (GL is current): bind the overlay panel, add the embedded
        overlays (Blue Marble hidden) and any overlays asked for before."""
        panel = self.layer_panel.overlays
        panel.bind(scene)
        if self._embedded_overlays:
            self._embedded_overlays = False
            try:  # the built-in layer types' layers: models, no GL here
                layers = scene.add_embedded_overlays(imagery=True)
                for layer in layers:
                    if layer.kind in ("imagery", "thematic"):
                        layer.set_visible(False)  # announced: listed and drawn hidden
            except Exception as exc:  # noqa: BLE001  any failure is one line in a dialog, the window keeps working
                self.errors.error(exc, "adding the embedded overlays")
        pending, self._pending_overlays = self._pending_overlays, []
        for path in pending:
            self.open_overlay(path)

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
        self.zoom_to_bounds(tuple(store.bounds))

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
            self.open_paths(paths)

    # -- shutdown ----------------------------------------------------------------------------
    def closeEvent(self, event: QCloseEvent) -> None:
        self.save_settings()
        self.globe.flight.stop()
        self.loader.shutdown()
        self.globe.release_gl()
        # Nothing may keep the released session (and its terrain caches) alive, and the
        # model (it may outlive the window) must not call the closed widgets.
        self.plugins.unbind()
        self.layer_panel.overlays.bind(None)
        self.subscriptions.clear()  # the children's too: they were handed this one
        super().closeEvent(event)

    def last_error(self) -> UserMessage | None:
        return self.errors.history[-1] if self.errors.history else None


def source_name(path: str, stem: bool = True) -> str:
    """What the window calls an opened source: a file's stem (``name`` with ``stem`` False),
    a store folder's name, or a store URL's last path segment (decoded; the host when the
    path is empty)."""
    if is_store_url(path):
        import urllib.parse

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
    from globeview.plugins.layer_dispatch import choose_layer_type

    p = Path(path)
    if p.is_dir():
        return "dem"
    if not p.exists():
        raise missing_path_error(p)
    if p.suffix.lower() in (".hgt", ".dem", ".bil", ".dt0", ".dt1", ".dt2", ".nc"):
        return "dem"
    if registry is None:
        from globeview.plugins.registry import PluginRegistry

        registry = PluginRegistry().discover()
    kind = choose_layer_type(registry, p)
    return "dem" if kind == "thematic" else "overlay"


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
