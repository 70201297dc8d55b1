"""Starting the desktop application: display check, QApplication with the OpenGL surface
format, the embedded data, the main window, and the exception hook."""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Sequence

from PyQt6.QtCore import QSettings
from PyQt6.QtGui import QSurfaceFormat
from PyQt6.QtWidgets import QApplication

from globeview.errors import GlobeviewError
from globeview.terrain.compose.stack import TerrainStack
from globeview.ui.errors import install_excepthook
from globeview.ui.globe_widget import surface_format
from globeview.ui.main_window import MainWindow
from globeview.ui.start import WindowStart, apply_start

ORGANIZATION = "globeview"
APPLICATION = "globeview"


def has_display(env: dict[str, str] | None = None) -> bool:
    """True when Qt has somewhere to open a window: an X or Wayland display, or a platform
    chosen explicitly with QT_QPA_PLATFORM."""
    env = os.environ if env is None else env
    return any(env.get(k) for k in ("DISPLAY", "WAYLAND_DISPLAY", "QT_QPA_PLATFORM"))


def create_application(argv: Sequence[str] | None = None) -> QApplication:
    """The QApplication (created once), with OpenGL 3.3 core as the default surface format
    (set before the application exists, as Qt requires for shared contexts)."""
    app = QApplication.instance()
    if app is None:
        QSurfaceFormat.setDefaultFormat(surface_format())
        app = QApplication(list(argv) if argv is not None else [sys.argv[0]])
        app.setOrganizationName(ORGANIZATION)
        app.setApplicationName(APPLICATION)
        app.setApplicationDisplayName("globeview")
    return app  # type: ignore[return-value]


def embedded_terrain() -> TerrainStack:
    """The embedded DEMs as a stack (ingested into the cache on first use)."""
    import sys

    from globeview.terrain.dem.data import embedded_dem_paths
    from globeview.terrain.embedded import embedded_stores, embedded_stores_ready
    from globeview.terrain.sources import store_path_for

    # Check the cache folder first: a bad one is one line, before any "preparing" line.
    stores_dir = store_path_for(embedded_dem_paths()[0]).parent
    try:
        stores_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise GlobeviewError(
            f"cannot prepare the embedded terrain: the cache folder {stores_dir} cannot be "
            f"made ({exc.strerror or exc}); set GLOBEVIEW_CACHE_DIR to a writable folder"
        ) from None
    if not embedded_stores_ready():
        print(  # noqa: T201  before the window exists, stderr is where this notice can go
            "globeview: preparing the embedded terrain (first run only, a few seconds)...",
            file=sys.stderr,
        )
    return embedded_stack(embedded_stores())


def embedded_stack(stores: list) -> TerrainStack:
    """The embedded stores (in `embedded_stores` order) as a stack whose layers are named
    after their DEMs (etopo20), not after their cache folders (etopo20-<hash>)."""
    from globeview.terrain.dem.data import embedded_dem_paths

    return TerrainStack.from_stores(stores, [p.stem for p in embedded_dem_paths()])


#: Set in the window's Qt settings once their plugin keys were copied into settings.json.
MIGRATED_KEY = "migrated/plugins_to_settings_json"


def plugin_registry(qsettings: QSettings):
    """The window's plugin registry, on the command line's settings file (``settings.json``
    in the config folder, `globeview.plugins.settings.default_settings`): what `globeview
    plugins enable/disable/set` stores is what the window uses, and the other way round.
    Plugin keys the window kept in its Qt settings before are copied over once (those the
    file lacks; the Qt settings keep them). A file that cannot be written costs the session's
    changes only (`TolerantSettings`), never the window. Overruns of the frame budget
    disable a plugin here (a slow provider would freeze the window)."""
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import TolerantSettings, default_settings
    from globeview.ui.plugin_host import QSettingsBackend

    backend = TolerantSettings(default_settings())
    # Once per Qt settings: a user who deletes settings.json to start afresh must not get the
    # old Qt values back at the next launch.
    if not qsettings.value(MIGRATED_KEY, False, type=bool):
        old = QSettingsBackend(qsettings)
        for key in qsettings.allKeys():
            if key.startswith("plugins/") and backend.get(key) is None:
                value = old.get(key)
                if value is not None:
                    backend.set(key, value)
        qsettings.setValue(MIGRATED_KEY, True)
    return PluginRegistry(backend, budget_policy="disable")


def run(
    files: Sequence[str] = (),
    settings: QSettings | None = None,
    start: WindowStart | None = None,
    project: str | None = None,
) -> int:
    """Open the window with the embedded data plus ``files`` (DEMs, stores, store URLs,
    overlay files), on ``start``'s view, LOD provider, tool and settings (`apply_start`),
    or on a ``project`` file (File > Open Project); returns the exit code."""
    logging.basicConfig(level=logging.WARNING, format="globeview: %(levelname)s: %(message)s")
    app = create_application()
    qsettings = settings or QSettings(ORGANIZATION, APPLICATION)
    start = start or WindowStart()
    window = MainWindow(
        embedded_terrain(),
        qsettings,
        plugin_registry(qsettings),
        camera=start.camera_object(),
        embedded_overlays=True,
    )
    previous = install_excepthook(window.errors)
    try:
        apply_start(window, start)
        window.show()
        if project is not None:
            window.projects.open(project)
        window.files.open_paths(list(files))
        return int(app.exec())
    finally:
        sys.excepthook = previous
