"""The window's generic tool UI, built from what a tool contribution declares — nothing here
(or in the main window) knows any particular tool:

- `ToolOptionsBar`: a toolbar shown while a tool is active, with a `SettingEditor` for each of
  the tool's `Setting`s and a button for each of its manifest commands;
- `CommandSpec` / `shortcut_clash`: the commands of the enabled tools (from their manifests)
  and the check that a command's shortcut does not take a key the window or another command
  already uses (a clash drops that shortcut with a one-line notice; the command keeps its
  button and menu entry).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from PyQt6.QtCore import Qt, pyqtSignal
from PyQt6.QtGui import QAction, QKeySequence
from PyQt6.QtWidgets import (
    QCheckBox,
    QComboBox,
    QDoubleSpinBox,
    QLabel,
    QSlider,
    QToolBar,
    QToolButton,
    QWidget,
)

from globeview.plugins.api import Setting
from globeview.plugins.manifest import Command
from globeview.ui.setting_editor import SettingEditor

#: Keys the globe's navigation takes without modifiers (navigation.Navigator.key, Home) and
#: Escape (leaves the tool): a plugin shortcut on one of them would steal it.
NAVIGATION_KEYS = ("W", "A", "S", "D", "Left", "Right", "Up", "Down", "+", "-", "=", "Home")


@dataclass(frozen=True)
class CommandSpec:
    """One command of one enabled tool: ``plugin`` and ``tool`` (contribution) names, and the
    manifest's `Command`."""

    plugin: str
    tool: str
    command: Command

    @property
    def key(self) -> str:
        """``"tool.command"``, the command's name in the window (object names, messages)."""
        return f"{self.tool}.{self.command.name}"


def portable(shortcut: str | QKeySequence) -> str:
    """A shortcut in Qt's portable text (how clashes are compared); "" when empty."""
    seq = shortcut if isinstance(shortcut, QKeySequence) else QKeySequence(shortcut)
    return seq.toString(QKeySequence.SequenceFormat.PortableText)


def shortcut_clash(shortcut: str, taken: dict[str, str]) -> str | None:
    """What already uses ``shortcut`` (``taken``: portable shortcut -> owner text, the
    navigation keys included by the caller), or None when it is free. A shortcut Qt cannot
    parse counts as taken by "nothing Qt knows"."""
    text = portable(shortcut)
    if not text:
        return "no key Qt knows"
    return taken.get(text)


def reserved_shortcuts(actions: Iterable[QAction]) -> dict[str, str]:
    """Portable shortcut -> owner text for the window's own actions and navigation keys."""
    taken = {portable(k): "globe navigation" for k in NAVIGATION_KEYS}
    for act in actions:
        for seq in act.shortcuts():
            text = portable(seq)
            if text:
                label = act.text().replace("&", "").rstrip("…").strip() or act.objectName()
                taken.setdefault(text, f"the window's {label!r}")
    return taken


#: Widest a setting's control grows in the bar (px).
MAX_EDITOR_PX = 260
#: What the bar says while no tool is active.
NO_TOOL_TEXT = " No tool active "


class ToolOptionsBar(QToolBar):
    """The active tool's settings and commands ("No tool active" while none is).

    The bar stays shown, its height fixed to that of a row of editors, so activating a tool
    never resizes the globe view (a frame before and after compares pixel for pixel).

    Signals:
        settingEdited(str, object): the user changed setting NAME to VALUE (coerced).
    """

    settingEdited = pyqtSignal(str, object)

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__("Tool options", parent)
        self.setObjectName("toolbar-tool-options")
        #: Setting name -> its editor, for the tool shown.
        self.editors: dict[str, SettingEditor] = {}
        #: The command actions shown as buttons, in manifest order.
        self.command_actions: list[QAction] = []
        self.tool_name: str | None = None
        self._tool_id: int | None = None
        self.title = QLabel()
        self.setMinimumHeight(self._row_height())
        self._clear()

    def _row_height(self) -> int:
        """The bar's height holding the tallest editors it may show."""
        samples = [
            QDoubleSpinBox(),
            QComboBox(),
            QSlider(Qt.Orientation.Horizontal),
            QCheckBox("x"),
            QToolButton(),
        ]
        for w in samples:
            self.addWidget(w)
        height = self.sizeHint().height()
        self.clear()
        return height

    def show_tool(
        self,
        name: str | None,
        tool: Any = None,
        label: str = "",
        commands: Iterable[QAction] = (),
    ) -> None:
        """Show tool ``name``'s settings (with its current values) and command buttons; None
        hides the bar. Rebuilt only when the tool object changes (`show_values` refreshes)."""
        if name is None or tool is None:
            if self.tool_name is not None:
                self.tool_name, self._tool_id = None, None
                self._clear()
            return
        if name == self.tool_name and id(tool) == self._tool_id:
            self.show_values(tool)
            return
        self._remove_all()
        self.editors, self.command_actions = {}, []
        self.tool_name, self._tool_id = name, id(tool)
        self.title = QLabel(f" {label or name}: ")
        self.addWidget(self.title)
        values = _values(tool)
        for spec in _settings(tool):
            editor = SettingEditor(spec, values.get(spec.name, spec.default))
            editor.setObjectName(f"setting-{name}-{spec.name}")
            editor.setMaximumWidth(MAX_EDITOR_PX)  # a toolbar would stretch a slider across
            editor.edited.connect(lambda v, n=spec.name: self.settingEdited.emit(n, v))
            if spec.type != "bool":  # a check box carries its own label
                caption = QLabel(f" {spec.label or spec.name} ")
                caption.setToolTip(spec.help)
                self.addWidget(caption)
            self.addWidget(editor)
            self.editors[spec.name] = editor
        self.command_actions = list(commands)
        if self.command_actions:
            self.addSeparator()
            for act in self.command_actions:
                self.addAction(act)

    def show_values(self, tool: Any) -> None:
        """Show the tool's current setting values (after a clamp, or a change elsewhere)."""
        values = _values(tool)
        for name, editor in self.editors.items():
            if name in values and editor.value() != values[name]:
                editor.show_value(values[name])

    def values(self) -> dict[str, Any]:
        """Setting name -> value shown."""
        return {name: editor.value() for name, editor in self.editors.items()}

    def _remove_all(self) -> None:
        """Take everything off the bar and free what the bar owns. `QToolBar.clear` only
        removes the actions: the QWidgetActions `addWidget` made (children of the bar) and
        the editors in them lived on, hundreds of widgets after a few tool switches."""
        for act in self.actions():
            self.removeAction(act)
            if act.parent() is self:  # addWidget's wrapper; the command actions are the window's
                act.deleteLater()

    def _clear(self) -> None:
        """Show no tool. The command actions belong to the window (their shortcuts live on);
        only this bar's buttons for them go."""
        self._remove_all()
        self.editors = {}
        self.command_actions = []
        self.title = QLabel(NO_TOOL_TEXT)
        self.title.setEnabled(False)
        self.addWidget(self.title)


def _settings(tool: Any) -> list[Setting]:
    """The tool's `Setting`s (ignoring anything else a hostile tool put there)."""
    try:
        return [s for s in (getattr(tool, "settings", ()) or ()) if isinstance(s, Setting)]
    except Exception:  # noqa: BLE001  a property that raises, a non-iterable: no controls, no crash
        return []


def _values(tool: Any) -> dict[str, Any]:
    values = getattr(tool, "values", None)
    return dict(values) if isinstance(values, dict) else {}
