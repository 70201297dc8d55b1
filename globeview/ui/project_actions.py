"""`ProjectActions`: File > Open Project… / Save Project… and the Bookmarks menu (issue #26
item 4). The project file and its checks are `globeview.model.project`; capturing and
applying a globe is `globeview.app.project`, shared with the Python API and ``globeview
render PROJECT.toml``, so the window, a script and the command line see one globe.

A project that cannot be read (not a project, a newer schema, a bad value, an unknown plugin
or setting) is one dialog and the window keeps what it showed. Layers whose files are missing
are listed in one dialog while the rest opens. Saving writes a temporary file beside the
target and moves it into place, so a read-only folder or a full disk leaves nothing partial.
"""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from PyQt6.QtCore import QEventLoop, QObject, QTimer
from PyQt6.QtGui import QAction, QKeySequence
from PyQt6.QtWidgets import QFileDialog, QInputDialog, QMenu

from globeview.app.project import (
    GlobeParts,
    OpenedDems,
    apply_project,
    check_plugins,
    open_dems,
    save_project,
)
from globeview.errors import GlobeviewError
from globeview.model.project import Project, read_project
from globeview.terrain.store.tile_store import TileStore
from globeview.ui.loading import open_store

__all__ = ["ProjectActions"]


def _open_store(text: str, crs: str | None, vdatum: str | None) -> TileStore:
    """A project's DEM as the window opens one (`open_store`: a remote store's first tiles
    fetched before the UI thread reads it)."""
    return open_store(text, None, vdatum, crs)


#: The file dialogs' filter.
PROJECT_FILTER = "globeview projects (*.toml)"


class ProjectActions(QObject):
    """The window's project and bookmark actions. ``window`` is the `MainWindow` (its
    ``model``, ``overlay_host``, ``plugins`` and ``errors`` are used).

    Attributes: ``open_action``, ``save_action`` (File menu), ``bookmarks_menu`` (Add
    Bookmark…, then one entry per bookmark: going there), ``path`` (the project last opened
    or saved, or None)."""

    def __init__(self, window: Any) -> None:
        super().__init__(window)
        self.window = window
        self.path: Path | None = None
        self.open_action = QAction("Open &Project…", window)
        self.open_action.setShortcut(QKeySequence("Ctrl+Alt+O"))  # Ctrl+Shift+O: Open Overlay
        self.open_action.triggered.connect(self.open_dialog)
        self.save_action = QAction("&Save Project…", window)
        self.save_action.setShortcut(QKeySequence("Ctrl+Shift+S"))
        self.save_action.triggered.connect(self.save_dialog)
        self.bookmarks_menu = QMenu("&Bookmarks", window)
        self.add_bookmark_action = QAction("&Add Bookmark…", window)
        self.add_bookmark_action.setShortcut(QKeySequence("Ctrl+D"))
        self.add_bookmark_action.triggered.connect(self.add_bookmark_dialog)
        window.subscriptions.connect(window.model.bookmarks.changed, self._fill_menu)
        self._fill_menu()

    # -- parts ---------------------------------------------------------------------------------
    def _parts(self) -> GlobeParts:
        w = self.window
        return GlobeParts(w.model, w.overlay_host, w.plugins.registry, w.tour_panel.tour)

    def _set_path(self, path: Path) -> None:
        """Remember the project (the dialogs start in its folder) and name it in the title."""
        self.path = path
        self.window.setWindowTitle(f"{path.name} — globeview")

    def _folder(self) -> str:
        return str(self.path.parent) if self.path is not None else str(Path.home())

    # -- projects --------------------------------------------------------------------------
    def save_dialog(self) -> None:
        path, _ = QFileDialog.getSaveFileName(
            self.window, "Save Project", self._folder(), PROJECT_FILTER
        )
        if path:
            self.save(path if path.lower().endswith(".toml") else f"{path}.toml")

    def save(self, path: str | Path) -> bool:
        """Save the window's globe to ``path``; one dialog if it cannot be written (nothing
        partial is left). Layers no file stands for are named in the status bar."""
        try:
            skipped = save_project(self._parts(), path)
        except GlobeviewError as exc:
            self.window.errors.error(exc, "Save Project")
            return False
        self._set_path(Path(path))
        for line in skipped:
            self.window.errors.notify(f"Save Project: {line}; left out")
        self.window.status.notice(f"saved project {Path(path).name}")
        return True

    def open_dialog(self) -> None:
        path, _ = QFileDialog.getOpenFileName(
            self.window, "Open Project", self._folder(), PROJECT_FILTER
        )
        if path:
            self.open(path)

    def open(self, path: str | Path) -> bool:
        """Show the project ``path`` in the window: its layers replace the window's, then
        its view, LOD provider, display, tool, bookmarks and tour (the Tour dock's). A file
        that cannot be read (or names an unknown plugin or setting) is one dialog and
        nothing changes; missing layers (and a tour with a bad keyframe) are listed in one
        dialog while the rest opens. The DEMs are opened (ingested into the tile cache if
        needed) on a worker thread while the window keeps drawing; the project
        actions wait meanwhile."""
        try:
            project = read_project(path)
            check_plugins(project, self.window.plugins.registry)
        except GlobeviewError as exc:
            self.window.errors.error(exc, "Open Project")
            return False
        base = Path(path).resolve().parent
        opened = self._open_dems(project, base, Path(path).name)
        if opened is None:  # the window was closed meanwhile
            return False
        self.window.tour_panel.stop()
        self.window.files.cancel_embedded_overlays()  # the project's overlays replace them
        try:
            problems = apply_project(project, base, self._parts(), opened=opened)
        except GlobeviewError as exc:  # a plugin changed while the DEMs were opened
            self.window.errors.error(exc, "Open Project")
            return False
        self.window.tour_panel.refresh()  # the Tour dock shows the project's tour
        for layer in self.window.model.terrain.layers:
            # As File > Open does: the UI thread never waits for a store's server (a tile
            # not fetched yet is fetched in the background; coarser ones stand in).
            layer.store.forbid_network_on(threading.get_ident())
        self._set_path(Path(path))
        self.window.plugins.refresh()  # the panel shows the provider's values from the file
        self.window.globe.request_frame()
        if problems:
            text = f"{len(problems)} layer(s) of {Path(path).name} not opened: "
            self.window.errors.error(GlobeviewError(text + "; ".join(problems)), "Open Project")
        else:
            self.window.status.notice(f"opened project {Path(path).name}")
        return True

    def _open_dems(self, project: Project, base: Path, name: str) -> OpenedDems | None:
        """`open_dems` on a worker thread, the window's events processed meanwhile (a nested
        event loop; the project actions are disabled). None if the window closed."""
        actions = (self.open_action, self.save_action)
        for action in actions:
            action.setEnabled(False)
        self.window.status.notice(f"opening project {name}…")
        pool = ThreadPoolExecutor(1, thread_name_prefix="globeview-project")
        try:
            future = pool.submit(open_dems, project, base, _open_store)
            loop = QEventLoop()
            timer = QTimer()
            timer.setInterval(20)
            timer.timeout.connect(lambda: loop.quit() if future.done() else None)
            timer.start()
            if not future.done():
                loop.exec()
            timer.stop()
            opened = future.result()  # a bug in opening is raised here, on the UI thread
        finally:
            pool.shutdown(wait=False)
            for action in actions:
                action.setEnabled(True)
        if not self.window.isVisible():
            for _spec, store in opened.stores:
                store.close()
            return None
        return opened

    # -- bookmarks -------------------------------------------------------------------------
    def add_bookmark_dialog(self) -> None:
        name, ok = QInputDialog.getText(self.window, "Add Bookmark", "Name of this view:")
        if ok and name.strip():
            self.add_bookmark(name)

    def add_bookmark(self, name: str) -> bool:
        """Bookmark the current view as ``name`` (replacing one of that name)."""
        try:
            self.window.model.bookmarks.add(name, self.window.model.camera.lonlat_hpr())
        except ValueError as exc:
            self.window.errors.error(GlobeviewError(str(exc)), "Add Bookmark")
            return False
        return True

    def go_to(self, name: str) -> None:
        """Put the camera at the bookmark ``name`` (its field of view stays)."""
        from globeview.model.camera import Camera

        model = self.window.model
        if name in model.bookmarks:
            lon, lat, height, heading, pitch, roll = model.bookmarks[name].pose
            fov = model.camera.fovy_deg
            model.camera = Camera.from_lonlat(lon, lat, height, heading, pitch, roll, fov)

    def _fill_menu(self) -> None:
        menu = self.bookmarks_menu
        menu.clear()
        menu.addAction(self.add_bookmark_action)
        names = self.window.model.bookmarks.names
        if names:
            menu.addSeparator()
        for name in names:
            action = QAction(name, menu)
            action.triggered.connect(lambda _=False, n=name: self.go_to(n))
            menu.addAction(action)
