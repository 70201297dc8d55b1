"""The layer panel: the overlays (imagery, thematic, vectors, points: `OverlayPanel`) in
their own group on top, then the DEM layers of the `TerrainStack`, topmost first.

Each row has a visibility checkbox; rows reorder by drag and drop or the ↑/↓ buttons (the
top row wins where layers overlap); "Zoom to" flies the camera over a layer and "Remove"
drops it. The panel edits the model's `TerrainStack` and shows it: it subscribes to the
model's ``terrain`` event, so a layer added, removed, moved or hidden anywhere (a DEM opened,
code, a plugin) is listed without anyone calling `refresh`; the view redraws on the same
event.
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

from globeview.model.globe import Globe
from globeview.terrain.store.tile_store import TileStore
from globeview.ui.overlay_panel import OverlayPanel
from globeview.ui.subscriptions import Subscriptions

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
_DATUM_NAMES = {"egm96": "EGM96 geoid", "egm2008": "EGM2008 geoid", "ellipsoid": "WGS84 ellipsoid"}


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
    """Lists the model's terrain layers and edits visibility, order and membership; the
    overlays group (`OverlayPanel`) lists its overlays.

    Signals:
        zoomRequested(object): (west, south, east, north) degrees of a layer to fly to.
    """

    zoomRequested = pyqtSignal(object)

    def __init__(
        self,
        model: Globe,
        parent: QWidget | None = None,
        subscriptions: Subscriptions | None = None,
    ) -> None:
        super().__init__(parent)
        self.model = model
        self.terrain = model.terrain
        self._updating = False
        self._editing = False  # the list already shows the change the stack announces
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
        self.overlays = OverlayPanel(model, subscriptions=subscriptions)
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
        #: The model subscriptions, the window's (cleared when it closes), or its own.
        self.subscriptions = Subscriptions() if subscriptions is None else subscriptions
        self.subscriptions.connect(model.events.terrain, self._terrain_changed)
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
                where = getattr(layer.store, "location", layer.store.path)  # folder or URL
                if getattr(layer.store, "offline", False):
                    where = f"{where} (offline: the tiles cached before)"
                item.setToolTip(
                    f"{where}\n{w:.3f}..{e:.3f}°E, {s:.3f}..{n:.3f}°N, "
                    f"levels 0..{layer.store.max_level}\n{datum_text(layer.store)}"
                )
                self.list.addItem(item)
                if layer.name == current:
                    self.list.setCurrentItem(item)
        finally:
            self._updating = False
        self._update_buttons()

    def _terrain_changed(self, *_args: object) -> None:
        if not self._editing:
            self.refresh()

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
        # Inside the list's own signal: the row already shows it (no rebuild under it).
        self._editing = True
        try:
            self.terrain.set_visible(item.data(NAME_ROLE), visible)
        finally:
            self._editing = False

    def set_visible(self, name: str, visible: bool) -> None:
        """Tick or untick a layer's checkbox (as a user click would)."""
        for r in range(self.list.count()):
            item = self.list.item(r)
            if item.data(NAME_ROLE) == name:
                item.setCheckState(Qt.CheckState.Checked if visible else Qt.CheckState.Unchecked)

    def _sync_order(self) -> None:
        """Make the stack's order follow the list's (list top = stack top)."""
        order = list(reversed(self.names()))
        self._editing = True  # the list shows the order already
        try:
            for index, name in enumerate(order):
                if self.terrain.layers[index].name != name:
                    self.terrain.move(name, index)
        finally:
            self._editing = False
        self._update_buttons()

    def move_selected(self, delta: int) -> None:
        """Move the selected row by ``delta`` rows (negative: up, i.e. drawn later)."""
        row = self.list.currentRow()
        new = row + delta
        if row < 0 or not (0 <= new < self.list.count()):
            return
        name = self.selected_name()
        self.terrain.move(name, len(self.terrain.layers) - 1 - new)  # the event lists it
        self.select(name)

    def zoom_selected(self) -> None:
        name = self.selected_name()
        layer = next((ly for ly in self.terrain.layers if ly.name == name), None)
        if layer is not None:
            self.zoomRequested.emit(tuple(layer.store.bounds))

    def remove_selected(self) -> None:
        name = self.selected_name()
        if name is None:
            return
        self.terrain.remove(name)  # the stack's event updates the list
