"""The overlay panel: the model's overlay layers (``Globe.overlays``: imagery, thematic,
vectors, points), topmost first.

Each row has a visibility checkbox; rows reorder by drag and drop or the ↑/↓ buttons (the
model's overlays are reordered, and the next frame composes the imagery drapes in the listed
order); "Remove" drops a layer. Below the list, the selected layer's style:
opacity for imagery/thematic drapes, colour and width (vectors) or size (points), the line
width of a drawing made of several line layers (a GIS file coloured by a field), a GIS
vector layer's field to colour by and to label with (the layer is reopened so, in its row),
and the selected layer's legend (its classes' colours and labels) when it has one. Every edit
goes to the layer's setters (`globeview.model.overlay_layers`), which announce a real
change (the layer's ``changed``, re-emitted by the Globe as ``globe.events.overlays``); the
panel shows what that event says, whoever changed the overlays (the window, code, a plugin),
and the view redraws on it. Nothing here draws.

Vectors and points are always drawn over the imagery drape (they are separate passes); the
order matters among drapes and among line layers.
"""

from __future__ import annotations

from typing import Any

from PyQt6.QtCore import Qt, pyqtSignal
from PyQt6.QtGui import QColor
from PyQt6.QtWidgets import (
    QAbstractItemView,
    QColorDialog,
    QComboBox,
    QDoubleSpinBox,
    QHBoxLayout,
    QLabel,
    QListWidget,
    QListWidgetItem,
    QPushButton,
    QSlider,
    QVBoxLayout,
    QWidget,
)

from globeview.errors import GlobeviewError
from globeview.model.globe import Globe
from globeview.ui.subscriptions import Subscriptions

ID_ROLE = Qt.ItemDataRole.UserRole
#: The colour-by / label choice meaning "no field".
NO_FIELD = "(none)"
DRAPE_KINDS = ("imagery", "thematic")
#: Short labels of the layer kinds shown in the rows.
KIND_LABELS = {
    "imagery": "imagery",
    "thematic": "thematic",
    "vector": "lines",
    "points": "points",
    "drawing": "drawing",
}


class OverlayList(QListWidget):
    """A list whose internal drag-and-drop moves report the new order."""

    reordered = pyqtSignal()

    def dropEvent(self, event) -> None:
        super().dropEvent(event)
        self.reordered.emit()


def layer_visible(layer: Any) -> bool:
    """Whether an overlay layer is shown (drapes: their imagery layer's flag)."""
    if layer.kind in DRAPE_KINDS:
        return bool(layer.layer.visible)
    return bool(layer.visible)


def layer_opacity(layer: Any) -> float:
    """A drape's opacity 0..1 (1 for vectors and points)."""
    return float(layer.layer.opacity) if layer.kind in DRAPE_KINDS else 1.0


class OverlayPanel(QWidget):
    """Lists the model's overlay layers and edits visibility, order, opacity, style and
    membership. Until an overlay host is bound (`bind`) the list is disabled."""

    def __init__(
        self,
        model: Globe,
        parent: QWidget | None = None,
        subscriptions: Subscriptions | None = None,
    ) -> None:
        super().__init__(parent)
        self.model = model
        #: Where layers are removed (`OverlayHost.remove`); None: the list is disabled.
        self.host: Any = None
        #: The last restyle that failed (one line), for the window's status.
        self.last_error = ""
        self._updating = False
        self._by_id: dict[int, Any] = {}

        self.list = OverlayList()
        self.list.setObjectName("overlay-list")
        self.list.setDragDropMode(QAbstractItemView.DragDropMode.InternalMove)
        self.list.setDefaultDropAction(Qt.DropAction.MoveAction)
        self.list.setSelectionMode(QAbstractItemView.SelectionMode.SingleSelection)
        self.list.setToolTip(
            "Tick to show an overlay; drag to reorder (drapes: the top one is composed last; "
            "lines and points are always drawn over the drapes)"
        )
        self.list.setMaximumHeight(140)
        self.list.itemChanged.connect(self._item_changed)
        self.list.reordered.connect(self._sync_order)
        self.list.currentRowChanged.connect(lambda _row: self._update_controls())

        self.up_button = QPushButton("↑")
        self.up_button.setToolTip("Move the overlay up")
        self.down_button = QPushButton("↓")
        self.down_button.setToolTip("Move the overlay down")
        self.remove_button = QPushButton("Remove")
        self.remove_button.setToolTip("Take the overlay off the globe")
        self.up_button.clicked.connect(lambda: self.move_selected(-1))
        self.down_button.clicked.connect(lambda: self.move_selected(+1))
        self.remove_button.clicked.connect(self.remove_selected)
        buttons = QHBoxLayout()
        for b in (self.up_button, self.down_button, self.remove_button):
            buttons.addWidget(b)

        # Style of the selected layer: opacity (drapes), colour + width/size (lines, points).
        self.opacity_label = QLabel("Opacity")
        self.opacity_slider = QSlider(Qt.Orientation.Horizontal)
        self.opacity_slider.setRange(0, 100)
        self.opacity_slider.setToolTip("Opacity of the selected drape (0..100 %)")
        self.opacity_value = QLabel()
        self.opacity_value.setMinimumWidth(36)
        self.opacity_slider.valueChanged.connect(self._opacity_changed)
        self.color_button = QPushButton("Colour…")
        self.color_button.setToolTip("Colour of the selected lines or points")
        self.color_button.clicked.connect(self.choose_color)
        self.width_label = QLabel("Width")
        self.width_spin = QDoubleSpinBox()
        self.width_spin.setRange(0.5, 40.0)
        self.width_spin.setSingleStep(0.5)
        self.width_spin.setDecimals(1)
        self.width_spin.setSuffix(" px")
        self.width_spin.valueChanged.connect(self._width_changed)
        style = QHBoxLayout()
        for w in (
            self.opacity_label,
            self.opacity_slider,
            self.opacity_value,
            self.color_button,
            self.width_label,
            self.width_spin,
        ):
            style.addWidget(w)

        # Styling by attribute (a GIS vector layer): the field to colour by, to label with.
        self.color_by_label = QLabel("Colour by")
        self.color_by_combo = QComboBox()
        self.color_by_combo.setToolTip("Colour the features by a field's values (a legend below)")
        self.label_label = QLabel("Label")
        self.label_combo = QComboBox()
        self.label_combo.setToolTip("Write a field's value beside each feature")
        self.color_by_combo.activated.connect(lambda _i: self._field_chosen("color_by"))
        self.label_combo.activated.connect(lambda _i: self._field_chosen("label"))
        fields = QHBoxLayout()
        for w in (self.color_by_label, self.color_by_combo, self.label_label, self.label_combo):
            fields.addWidget(w)

        #: The selected layer's legend (rich text: a coloured square and a label per class).
        self.legend_label = QLabel()
        self.legend_label.setObjectName("overlay-legend")
        self.legend_label.setTextFormat(Qt.TextFormat.RichText)
        self.legend_label.setWordWrap(True)
        self.legend_label.setToolTip("The colours of the selected layer's classes")

        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.list)
        layout.addLayout(buttons)
        layout.addLayout(style)
        layout.addLayout(fields)
        layout.addWidget(self.legend_label)
        #: The model subscriptions, the window's (cleared when it closes), or its own.
        self.subscriptions = Subscriptions() if subscriptions is None else subscriptions
        self.subscriptions.connect(model.events.overlays, self.refresh)
        self.refresh()

    # -- model ----------------------------------------------------------------------------
    def bind(self, host: Any) -> None:
        """Edit the overlays through ``host`` (the window's `OverlayHost`; None: none, the
        list is disabled). No edit needs GL: the session makes, updates and frees the
        layers' GPU side (an API 1.0 plugin layer's own attach/detach/set_visible too) at
        the next frame."""
        self.host = host
        self.refresh()

    def layers(self) -> list:
        """The model's overlay layers, bottom first."""
        return list(self.model.overlays)

    def names(self) -> list[str]:
        """Overlay names as listed, topmost first."""
        return [self.layer_at(r).name for r in range(self.list.count())]

    def layer_at(self, row: int) -> Any:
        return self._by_id[self.list.item(row).data(ID_ROLE)]

    def find(self, name: str) -> Any:
        """The topmost overlay layer called ``name`` (None if there is none)."""
        return next((ly for ly in reversed(self.layers()) if ly.name == name), None)

    def selected_layer(self) -> Any:
        row = self.list.currentRow()
        return None if row < 0 else self.layer_at(row)

    def refresh(self, *_args: object) -> None:
        """Show the model's overlays (its ``overlays`` event): the same layers in the same
        order are updated in place (an edit here is not rebuilt under itself); otherwise the
        rows are rebuilt, keeping the selection."""
        self.list.setEnabled(self.host is not None)
        listed = [self.list.item(r).data(ID_ROLE) for r in range(self.list.count())]
        if listed and listed == [id(ly) for ly in reversed(self.layers())]:
            self._updating = True
            try:
                for r in range(self.list.count()):
                    self.list.item(r).setCheckState(
                        Qt.CheckState.Checked
                        if layer_visible(self.layer_at(r))
                        else Qt.CheckState.Unchecked
                    )
            finally:
                self._updating = False
            self._update_controls()
            return
        current = self.selected_layer()
        self._updating = True
        try:
            self.list.clear()
            self._by_id = {}
            for layer in reversed(self.layers()):
                self._by_id[id(layer)] = layer
                item = QListWidgetItem(f"{layer.name}  ({KIND_LABELS.get(layer.kind, layer.kind)})")
                item.setData(ID_ROLE, id(layer))
                flags = item.flags() | Qt.ItemFlag.ItemIsUserCheckable
                flags |= Qt.ItemFlag.ItemIsDragEnabled
                item.setFlags(flags & ~Qt.ItemFlag.ItemIsDropEnabled)
                item.setCheckState(
                    Qt.CheckState.Checked if layer_visible(layer) else Qt.CheckState.Unchecked
                )
                item.setToolTip(f"{layer.kind} overlay {layer.name}")
                self.list.addItem(item)
                if layer is current:
                    self.list.setCurrentItem(item)
        finally:
            self._updating = False
        self._update_controls()

    def select(self, layer: Any) -> None:
        for r in range(self.list.count()):
            if self.layer_at(r) is layer:
                self.list.setCurrentRow(r)
                return

    def _update_controls(self) -> None:
        row = self.list.currentRow()
        layer = self.selected_layer()
        self.up_button.setEnabled(row > 0)
        self.down_button.setEnabled(0 <= row < self.list.count() - 1)
        self.remove_button.setEnabled(layer is not None)
        drape = layer is not None and layer.kind in DRAPE_KINDS
        styled = layer is not None and layer.kind in ("vector", "points")
        lines = _line_parts(layer)
        for w in (self.opacity_label, self.opacity_slider, self.opacity_value):
            w.setVisible(drape)
        self.color_button.setVisible(styled)
        for w in (self.width_label, self.width_spin):
            w.setVisible(styled or bool(lines))
        legend = list(getattr(layer, "legend", None) or []) if layer is not None else []
        self.legend_label.setText(legend_html(legend))
        self.legend_label.setVisible(bool(legend))
        self._show_fields(layer)
        self._updating = True
        try:
            if drape:
                pct = round(layer_opacity(layer) * 100)
                self.opacity_slider.setValue(pct)
                self.opacity_value.setText(f"{pct} %")
            if styled:
                self.width_label.setText("Width" if layer.kind == "vector" else "Size")
                self.width_spin.setValue(float(_size_of(layer)))
                self._show_color(layer.color)
            elif lines:
                self.width_label.setText("Width")
                self.width_spin.setValue(float(lines[0].width_px))
        finally:
            self._updating = False

    def _show_fields(self, layer: Any) -> None:
        """The colour-by and label choices of a GIS vector layer (hidden for others)."""
        fields = None
        if layer is not None and self.host is not None and hasattr(self.host, "vector_fields"):
            try:
                fields = self.host.vector_fields(layer)
            except GlobeviewError:  # its file went away: nothing to choose from
                fields = None
        for w in (self.color_by_label, self.color_by_combo, self.label_label, self.label_combo):
            w.setVisible(fields is not None)
        if fields is None:
            return
        style = self.host.opened_style(layer) or {}
        for combo, key in ((self.color_by_combo, "color_by"), (self.label_combo, "label")):
            combo.blockSignals(True)
            combo.clear()
            combo.addItems([NO_FIELD, *fields])
            current = style.get(key)
            combo.setCurrentIndex(fields.index(current) + 1 if current in fields else 0)
            combo.blockSignals(False)

    def _field_chosen(self, key: str) -> None:
        combo = self.color_by_combo if key == "color_by" else self.label_combo
        self.set_field(self.selected_layer(), key, combo.currentText())

    def set_field(self, layer: Any, key: str, field: str) -> Any:
        """Reopen a GIS vector layer coloured by (``key="color_by"``) or labelled with
        (``"label"``) ``field`` (`NO_FIELD`: none); the new layer takes the old one's row and
        is selected. Returns it (None when nothing changed or the file cannot be read: the
        old layer stays, the reason in `last_error`)."""
        if layer is None or self.host is None:
            return None
        value = None if field == NO_FIELD else field
        if (self.host.opened_style(layer) or {}).get(key) == value:
            return None
        try:
            new = self.host.restyle(layer, **{key: value})
        except GlobeviewError as exc:
            self.last_error = str(exc)
            self._update_controls()
            return None
        self.select(new)
        return new

    def _show_color(self, rgba: tuple) -> None:
        c = QColor.fromRgbF(*(float(v) for v in rgba[:3]))
        text = "#000" if c.lightnessF() > 0.5 else "#fff"
        self.color_button.setStyleSheet(f"background-color: {c.name()}; color: {text};")

    # -- edits ----------------------------------------------------------------------------
    def set_visible(self, layer: Any, visible: bool) -> None:
        """Tick or untick an overlay's checkbox (as a user click would)."""
        for r in range(self.list.count()):
            if self.layer_at(r) is layer:
                self.list.item(r).setCheckState(
                    Qt.CheckState.Checked if visible else Qt.CheckState.Unchecked
                )

    def _item_changed(self, item: QListWidgetItem) -> None:
        if self._updating or self.host is None:
            return
        layer = self._by_id[item.data(ID_ROLE)]
        # The layer announces the change (globe.events.overlays): the view redraws.
        layer.set_visible(item.checkState() == Qt.CheckState.Checked)

    def set_opacity(self, layer: Any, opacity: float) -> None:
        """Set a drape's opacity (0..1); the slider follows when it is selected."""
        if layer.kind not in DRAPE_KINDS or self.host is None:
            return
        layer.set_opacity(opacity)  # announced by the layer; the slider follows

    def _opacity_changed(self, pct: int) -> None:
        self.opacity_value.setText(f"{pct} %")
        layer = self.selected_layer()
        if self._updating or layer is None:
            return
        self.set_opacity(layer, pct / 100.0)

    def set_color(self, layer: Any, color: QColor) -> None:
        """Set a vector/points layer's colour (effective on the next frame)."""
        if layer.kind not in ("vector", "points"):
            return
        rgba = (color.redF(), color.greenF(), color.blueF(), color.alphaF())
        layer.set_style(color=rgba)  # announced by the layer; the button follows

    def choose_color(self) -> None:
        """Pick the selected layer's colour with a colour dialog."""
        layer = self.selected_layer()
        if layer is None or layer.kind not in ("vector", "points"):
            return
        initial = QColor.fromRgbF(*(float(v) for v in layer.color))
        alpha = QColorDialog.ColorDialogOption.ShowAlphaChannel
        color = QColorDialog.getColor(initial, self, f"Colour of {layer.name}", alpha)
        if color.isValid():
            self.set_color(layer, color)

    def set_width(self, layer: Any, px: float) -> None:
        """Line width (vectors, a drawing's line parts) or placemark size (points), in
        pixels."""
        if layer.kind == "vector" or (layer.kind == "drawing" and _line_parts(layer)):
            layer.set_style(width_px=float(px))  # announced by the layer
        elif layer.kind == "points":
            layer.set_style(size_px=float(px))

    def _width_changed(self, px: float) -> None:
        layer = self.selected_layer()
        if self._updating or layer is None:
            return
        self.set_width(layer, px)

    def _sync_order(self) -> None:
        """Make the model's order follow the list's (after a drag)."""
        order = [self.layer_at(r) for r in reversed(range(self.list.count()))]
        self._reorder(order)

    def move_selected(self, delta: int) -> None:
        """Move the selected row by ``delta`` rows (negative: up, i.e. on top)."""
        row = self.list.currentRow()
        new = row + delta
        if row < 0 or not (0 <= new < self.list.count()):
            return
        listed = [self.layer_at(r) for r in range(self.list.count())]
        listed.insert(new, listed.pop(row))
        self._reorder(list(reversed(listed)))
        self.select(listed[new])

    def _reorder(self, order: list) -> None:
        """Put the model's overlays in ``order`` (bottom first): one event, which lists them
        here and redraws (the renderer composes drapes and lines in the model's order)."""
        if self.host is None or order == self.layers():
            self.refresh()
            return
        self.model.set_overlay_order(order)

    def remove_selected(self) -> None:
        layer = self.selected_layer()
        if layer is not None:
            self.remove(layer)

    def remove(self, layer: Any) -> None:
        """Take an overlay off the globe and out of the model (its event updates the list)."""
        if self.host is None:
            return
        self.host.remove(layer)


def _line_parts(layer: Any) -> list:
    """A drawing's line layers (none for another kind)."""
    if layer is None or layer.kind != "drawing":
        return []
    return [p for p in getattr(layer, "parts", ()) if getattr(p, "kind", "") == "vector"]


def legend_html(entries: list) -> str:
    """A legend (`LegendEntry` rows: label, RGBA 0..1) as rich text, one row a line."""
    import html

    rows = []
    for e in entries[:24]:
        c = QColor.fromRgbF(*(float(v) for v in e.color[:3]))
        rows.append(f'<span style="color:{c.name()}">&#9632;</span> {html.escape(e.label)}')
    if len(entries) > 24:
        rows.append(f"… {len(entries) - 24} more")
    return "<br>".join(rows)


def _size_of(layer: Any) -> float:
    return float(layer.width_px if layer.kind == "vector" else layer.size_px)
