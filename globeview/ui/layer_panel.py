"""The layer panel: the overlays (imagery, thematic, vectors, points: `OverlayPanel`) in
their own group on top, then the DEM layers of the `TerrainStack`, topmost first.

Each row has a visibility checkbox; rows reorder by drag and drop or the ↑/↓ buttons (the
top row wins where layers overlap); "Zoom to" flies the camera over a layer and "Remove"
drops it. The panel edits the stack directly and emits ``changed`` so the view redraws.
"""

from __future__ import annotations

from PyQt6.QtCore import Qt, pyqtSignal
from PyQt6.QtWidgets import (
    QAbstractItemView,
    QComboBox,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QListWidget,
    QListWidgetItem,
    QPushButton,
    QVBoxLayout,
    QWidget,
)

from globeview.terrain.stack import TerrainStack
from globeview.terrain.store import TileStore
from globeview.ui.overlay_panel import OverlayPanel

NAME_ROLE = Qt.ItemDataRole.UserRole


class LayerList(QListWidget):
    """A list whose internal drag-and-drop moves report the new order."""

    reordered = pyqtSignal()

    def dropEvent(self, event) -> None:
        super().dropEvent(event)
        self.reordered.emit()


#: (label, --vdatum value) of the datum choice; None: what the file says.
VDATUM_CHOICES: tuple[tuple[str, str | None], ...] = (
    ("vertical datum from the file", None),
    ("heights above the EGM96 geoid", "egm96"),
    ("heights above the WGS84 ellipsoid", "ellipsoid"),
)
_DATUM_NAMES = {"egm96": "EGM96 geoid", "ellipsoid": "WGS84 ellipsoid"}


def datum_text(store: TileStore) -> str:
    """Where a store's heights came from, for people: "heights: EGM96 geoid (SRTM .hgt
    default), stored above the ellipsoid" (one entry per source)."""
    parts = []
    for src in store.manifest.sources:
        name = _DATUM_NAMES.get(src.vertical_datum, src.vertical_datum)
        parts.append(f"{name} ({src.vertical_datum_source})")
    if not parts:
        return "heights: vertical datum not recorded"
    return f"heights: {'; '.join(parts)}, stored above the ellipsoid"


class LayerPanel(QWidget):
    """Lists the stack's layers and edits visibility, order and membership.

    Signals:
        changed(): the stack changed (redraw).
        zoomRequested(object): (west, south, east, north) degrees of a layer to fly to.
    """

    changed = pyqtSignal()
    zoomRequested = pyqtSignal(object)

    def __init__(self, terrain: TerrainStack, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.terrain = terrain
        self._updating = False
        self.list = LayerList()
        self.list.setDragDropMode(QAbstractItemView.DragDropMode.InternalMove)
        self.list.setDefaultDropAction(Qt.DropAction.MoveAction)
        self.list.setSelectionMode(QAbstractItemView.SelectionMode.SingleSelection)
        self.list.setToolTip("Tick to show a layer; drag to reorder (the top layer wins)")
        self.list.itemChanged.connect(self._item_changed)
        self.list.reordered.connect(self._sync_order)
        self.list.itemDoubleClicked.connect(lambda _item: self.zoom_selected())
        self.list.currentRowChanged.connect(lambda _row: self._update_buttons())

        self.up_button = QPushButton("↑")
        self.up_button.setToolTip("Move the layer up (drawn on top)")
        self.down_button = QPushButton("↓")
        self.down_button.setToolTip("Move the layer down")
        self.zoom_button = QPushButton("Zoom to")
        self.zoom_button.setToolTip("Fly the camera over the layer")
        self.remove_button = QPushButton("Remove")
        self.up_button.clicked.connect(lambda: self.move_selected(-1))
        self.down_button.clicked.connect(lambda: self.move_selected(+1))
        self.zoom_button.clicked.connect(self.zoom_selected)
        self.remove_button.clicked.connect(self.remove_selected)

        #: Vertical datum of the DEMs opened next (``--vdatum`` of the command line).
        self.vdatum_combo = QComboBox()
        for label, value in VDATUM_CHOICES:
            self.vdatum_combo.addItem(label, value)
        self.vdatum_combo.setToolTip(
            "Vertical datum of DEMs opened from now on: from the file (its CRS, or SRTM and "
            "sea-level DEMs as EGM96), or declared. Heights are stored above the ellipsoid."
        )

        buttons = QHBoxLayout()
        for b in (self.up_button, self.down_button, self.zoom_button, self.remove_button):
            buttons.addWidget(b)
        #: The overlay layers (bound to the session once the globe's GL is up).
        self.overlays = OverlayPanel()
        overlay_box = QGroupBox("Overlays")
        overlay_box.setObjectName("overlays-group")
        QVBoxLayout(overlay_box).addWidget(self.overlays)
        terrain_box = QGroupBox("Terrain (DEM)")
        terrain_layout = QVBoxLayout(terrain_box)
        terrain_layout.addWidget(self.list)
        terrain_layout.addLayout(buttons)
        datum_row = QHBoxLayout()
        datum_row.addWidget(QLabel("Open DEMs as"))
        datum_row.addWidget(self.vdatum_combo, 1)
        terrain_layout.addLayout(datum_row)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(4, 4, 4, 4)
        layout.addWidget(overlay_box)
        layout.addWidget(terrain_box)
        self.refresh()

    # -- view of the model ----------------------------------------------------------------
    def names(self) -> list[str]:
        """Layer names as listed, topmost first."""
        return [self.list.item(r).data(NAME_ROLE) for r in range(self.list.count())]

    def refresh(self) -> None:
        """Rebuild the rows from the stack (keeps the selection by name)."""
        current = self.selected_name()
        self._updating = True
        try:
            self.list.clear()
            for layer in reversed(self.terrain.layers):
                item = QListWidgetItem(layer.name)
                item.setData(NAME_ROLE, layer.name)
                flags = item.flags() | Qt.ItemFlag.ItemIsUserCheckable
                flags |= Qt.ItemFlag.ItemIsDragEnabled
                item.setFlags(flags & ~Qt.ItemFlag.ItemIsDropEnabled)
                item.setCheckState(
                    Qt.CheckState.Checked if layer.visible else Qt.CheckState.Unchecked
                )
                w, s, e, n = layer.store.bounds
                item.setToolTip(
                    f"{layer.store.path}\n{w:.3f}..{e:.3f}°E, {s:.3f}..{n:.3f}°N, "
                    f"levels 0..{layer.store.max_level}\n{datum_text(layer.store)}"
                )
                self.list.addItem(item)
                if layer.name == current:
                    self.list.setCurrentItem(item)
        finally:
            self._updating = False
        self._update_buttons()

    def vdatum(self) -> str | None:
        """The vertical datum chosen for DEMs opened next (None: from the file)."""
        return self.vdatum_combo.currentData()

    def selected_name(self) -> str | None:
        item = self.list.currentItem()
        return None if item is None else item.data(NAME_ROLE)

    def select(self, name: str) -> None:
        for r in range(self.list.count()):
            if self.list.item(r).data(NAME_ROLE) == name:
                self.list.setCurrentRow(r)
                return

    def _update_buttons(self) -> None:
        row = self.list.currentRow()
        has = row >= 0
        self.up_button.setEnabled(has and row > 0)
        self.down_button.setEnabled(has and row < self.list.count() - 1)
        self.zoom_button.setEnabled(has)
        self.remove_button.setEnabled(has)

    # -- edits ----------------------------------------------------------------------------
    def _item_changed(self, item: QListWidgetItem) -> None:
        if self._updating:
            return
        visible = item.checkState() == Qt.CheckState.Checked
        self.terrain.set_visible(item.data(NAME_ROLE), visible)
        self.changed.emit()

    def set_visible(self, name: str, visible: bool) -> None:
        """Tick or untick a layer's checkbox (as a user click would)."""
        for r in range(self.list.count()):
            item = self.list.item(r)
            if item.data(NAME_ROLE) == name:
                item.setCheckState(Qt.CheckState.Checked if visible else Qt.CheckState.Unchecked)

    def _sync_order(self) -> None:
        """Make the stack's order follow the list's (list top = stack top)."""
        order = list(reversed(self.names()))
        for index, name in enumerate(order):
            if self.terrain.layers[index].name != name:
                self.terrain.move(name, index)
        self.changed.emit()
        self._update_buttons()

    def move_selected(self, delta: int) -> None:
        """Move the selected row by ``delta`` rows (negative: up, i.e. drawn later)."""
        row = self.list.currentRow()
        new = row + delta
        if row < 0 or not (0 <= new < self.list.count()):
            return
        name = self.selected_name()
        self.terrain.move(name, len(self.terrain.layers) - 1 - new)
        self.refresh()
        self.select(name)
        self.changed.emit()

    def zoom_selected(self) -> None:
        name = self.selected_name()
        layer = next((ly for ly in self.terrain.layers if ly.name == name), None)
        if layer is not None:
            self.zoomRequested.emit(tuple(layer.store.bounds))

    def remove_selected(self) -> None:
        name = self.selected_name()
        if name is None:
            return
        self.terrain.remove(name)
        self.refresh()
        self.changed.emit()
