"""The plugin manager panel: every discovered plugin (name, version, kind, description,
enabled switch, status and error), the active LOD provider, the screen-space error threshold
tau, and the active provider's own settings, editable live (each change takes effect on the
next frame; the editors are the `SettingEditor`s tools get too).

A failure stays visible here: the plugin's row reads "failed: <reason>" ("partial: <reason>"
when only some of its contributions failed; red, with the reason in its tooltip) and, after a
fallback, a red line under the provider choice says which
provider failed and why until the user picks one again."""

from __future__ import annotations

from typing import Any

from PyQt6.QtCore import Qt
from PyQt6.QtWidgets import (
    QComboBox,
    QFormLayout,
    QGroupBox,
    QHBoxLayout,
    QHeaderView,
    QLabel,
    QSlider,
    QTreeWidget,
    QTreeWidgetItem,
    QVBoxLayout,
    QWidget,
)

from globeview.plugins.api import Setting
from globeview.ui.plugin_host import PluginHost
from globeview.ui.setting_editor import SettingEditor
from globeview.ui.subscriptions import Subscriptions

COLUMNS = ("Plugin", "Version", "Kind", "Status", "Description")
#: tau slider: tenths of a pixel, 0.5 .. 32 px.
TAU_MIN_PX, TAU_MAX_PX = 0.5, 32.0


class PluginPanel(QWidget):
    """View of a `PluginHost` and of the model's tau (``host.model.tau_px``): moving the
    slider sets the model's tau, and a tau set anywhere (code, a plugin, settings) moves the
    slider (the panel subscribes to ``model.events.tau_px``)."""

    def __init__(
        self,
        host: PluginHost,
        parent: QWidget | None = None,
        subscriptions: Subscriptions | None = None,
    ) -> None:
        super().__init__(parent)
        self.host = host
        self.model = host.model
        self._showing_tau = False
        self._updating = False
        self.tree = QTreeWidget()
        self.tree.setColumnCount(len(COLUMNS))
        self.tree.setHeaderLabels(COLUMNS)
        self.tree.setRootIsDecorated(False)
        self.tree.header().setSectionResizeMode(QHeaderView.ResizeMode.ResizeToContents)
        self.tree.header().setStretchLastSection(True)
        self.tree.setToolTip("Tick to enable a plugin (remembered across sessions)")
        self.tree.itemChanged.connect(self._item_changed)

        self.lod_combo = QComboBox()
        self.lod_combo.setToolTip("The level-of-detail algorithm choosing the tiles each frame")
        self.lod_combo.currentIndexChanged.connect(self._combo_changed)

        self.tau_slider = QSlider(Qt.Orientation.Horizontal)
        self.tau_slider.setRange(int(TAU_MIN_PX * 10), int(TAU_MAX_PX * 10))
        self.tau_slider.setToolTip(
            "Screen-space error threshold tau: the most a tile's geometric error may cover "
            "on screen, in pixels (smaller: more detail, more triangles)"
        )
        self.tau_label = QLabel()
        self.tau_slider.valueChanged.connect(self._tau_moved)
        self._show_tau()

        self.settings_box = QGroupBox("Provider settings")
        self.settings_form = QFormLayout(self.settings_box)
        self.setting_widgets: dict[str, SettingEditor] = {}
        #: The last fallback's reason (hidden while the chosen provider draws).
        self.fallback_label = QLabel()
        self.fallback_label.setWordWrap(True)
        self.fallback_label.setStyleSheet("color: #c0392b")
        self.fallback_label.hide()

        lod_form = QFormLayout()
        lod_form.addRow("LOD provider", self.lod_combo)
        tau_row = QHBoxLayout()
        tau_row.addWidget(self.tau_slider, 1)
        tau_row.addWidget(self.tau_label)
        lod_form.addRow("tau", tau_row)
        lod_form.addRow(self.fallback_label)

        layout = QVBoxLayout(self)
        layout.setContentsMargins(4, 4, 4, 4)
        layout.addWidget(self.tree, 1)
        layout.addLayout(lod_form)
        layout.addWidget(self.settings_box)

        host.changed.connect(self.refresh)
        host.lodChanged.connect(lambda _name: self.refresh())
        #: The model subscriptions, the window's (cleared when it closes), or its own.
        self.subscriptions = Subscriptions() if subscriptions is None else subscriptions
        self.subscriptions.connect(self.model.events.tau_px, self._show_tau)
        self.refresh()

    # -- refresh from the host ------------------------------------------------------------
    def refresh(self) -> None:
        self._updating = True
        try:
            self.tree.clear()
            for rec in self.host.records():
                m = rec.manifest
                # 'partial': enabled, some contributions failed (the reason names them).
                label = "partial" if rec.status == "partial" else "failed"
                status = rec.status if not rec.error else f"{label}: {rec.error}"
                item = QTreeWidgetItem(
                    [
                        rec.name,
                        rec.version,
                        ", ".join(rec.kinds),
                        status,
                        m.description if m else "",
                    ]
                )
                item.setData(0, Qt.ItemDataRole.UserRole, rec.name)
                flags = item.flags() | Qt.ItemFlag.ItemIsUserCheckable
                if m is None:
                    flags &= ~Qt.ItemFlag.ItemIsEnabled
                item.setFlags(flags)
                state = Qt.CheckState.Checked if rec.enabled else Qt.CheckState.Unchecked
                item.setCheckState(0, state)
                tip = f"{rec.source}" + (f"\n{rec.error}" if rec.error else "")
                for col in range(len(COLUMNS)):
                    item.setToolTip(col, tip)
                if rec.status == "failed":
                    item.setForeground(3, Qt.GlobalColor.red)
                self.tree.addTopLevelItem(item)

            self.lod_combo.clear()
            for name, label in self.host.providers().items():
                self.lod_combo.addItem(label, name)
            idx = self.lod_combo.findData(self.host.active)
            self.lod_combo.setCurrentIndex(max(idx, 0))
            why = self.host.fallback_reason
            self.fallback_label.setText(f"{why}; using {self.host.active}" if why else "")
            self.fallback_label.setToolTip(why)
            self.fallback_label.setVisible(bool(why))
            self._build_settings()
        finally:
            self._updating = False

    def _build_settings(self) -> None:
        while self.settings_form.rowCount():
            self.settings_form.removeRow(0)
        self.setting_widgets = {}
        provider = self.host.provider()
        specs: list[Setting] = list(getattr(provider, "settings", ()) or ())
        values: dict[str, Any] = dict(getattr(provider, "values", {}) or {})
        if not specs:
            self.settings_form.addRow(QLabel("No settings"))
            return
        for spec in specs:
            w = SettingEditor(spec, values.get(spec.name, spec.default))
            w.edited.connect(self._settings_edited)
            self.setting_widgets[spec.name] = w
            label = "" if spec.type == "bool" else (spec.label or spec.name)
            self.settings_form.addRow(label, w)

    def setting_values(self) -> dict[str, Any]:
        """The values shown in the settings editors."""
        return {name: w.value() for name, w in self.setting_widgets.items()}

    # -- user edits -----------------------------------------------------------------------
    def _item_changed(self, item: QTreeWidgetItem, column: int) -> None:
        if self._updating or column != 0:
            return
        name = item.data(0, Qt.ItemDataRole.UserRole)
        self.host.set_enabled(name, item.checkState(0) == Qt.CheckState.Checked)

    def _combo_changed(self, index: int) -> None:
        if self._updating or index < 0:
            return
        self.host.choose(self.lod_combo.itemData(index))

    def _settings_edited(self, *_args: Any) -> None:
        if self._updating:
            return
        self.host.configure(self.setting_values())

    def set_tau(self, tau_px: float) -> None:
        """Move the slider to ``tau_px`` (clamped to its range) as a user would: the model's
        tau follows."""
        self.tau_slider.setValue(round(min(max(tau_px, TAU_MIN_PX), TAU_MAX_PX) * 10))

    def tau(self) -> float:
        """The model's tau (pixels)."""
        return self.model.tau_px

    def _tau_moved(self, value: int) -> None:
        if not self._showing_tau:
            self.model.tau_px = value / 10.0

    def _show_tau(self, *_args: object) -> None:
        """Show the model's tau: the label says it exactly, the slider as near as its range
        and tenths allow (moving it there does not change the model)."""
        tau = self.model.tau_px
        self._showing_tau = True
        try:
            self.tau_slider.setValue(round(min(max(tau, TAU_MIN_PX), TAU_MAX_PX) * 10))
        finally:
            self._showing_tau = False
        self.tau_label.setText(f"{tau:.1f} px")
