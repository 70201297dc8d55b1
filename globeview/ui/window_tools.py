"""The window's tools: the Tools toolbar and menu, one checkable action per enabled tool
plugin (rebuilt when plugins are enabled or disabled, at most one active), the actions of the
commands tools declare in their manifests (Tools menu entries, buttons in the Tool options
bar, keyboard shortcuts), the Tool options bar itself, and activating a tool with the report
of one that fails to. Everything comes from what a tool declares (its `Setting`s, its
``[[contributions.commands]]``), the same for built-in and installed tools: no tool-specific
code here.
"""

from __future__ import annotations

import logging
from typing import Any

from PyQt6.QtCore import QKeyCombination, Qt
from PyQt6.QtGui import QAction, QActionGroup, QKeySequence
from PyQt6.QtWidgets import QMainWindow, QToolBar

from globeview.errors import GlobeviewError
from globeview.model.globe import Globe
from globeview.ui.errors import ErrorReporter
from globeview.ui.globe_widget import GlobeWidget
from globeview.ui.plugin_host import PluginHost
from globeview.ui.status import StatusBar
from globeview.ui.tool_options import (
    CommandSpec,
    ToolOptionsBar,
    portable,
    reserved_shortcuts,
    shortcut_clash,
)

log = logging.getLogger("globeview.ui")


class WindowTools:
    """The tools of ``window``: adds the Tools toolbar, the Tools menu (after the menus the
    window has so far) and the Tool options bar (a toolbar row of its own) to it; the
    actions are the window's children (their shortcuts work whichever tool is active).

    Args:
        window: the main window the bars, menu and actions go on.
        globe: the `GlobeWidget` (the session's tools, activation, redraws).
        model: the `Globe` (its ``tool``).
        plugins: the `PluginHost` (registry, failure reasons, notices).
        errors, status: where one-line notices and activation reports go.
    """

    def __init__(
        self,
        window: QMainWindow,
        globe: GlobeWidget,
        model: Globe,
        plugins: PluginHost,
        errors: ErrorReporter,
        status: StatusBar,
    ) -> None:
        self.window = window
        self.globe = globe
        self.model = model
        self.plugins = plugins
        self.errors = errors
        self.status = status
        #: The tool asked for by `set_tool` until a frame is drawn with it (its activation
        #: can fail until then).
        self._activating: str | None = None
        self.toolbar = QToolBar("Tools", window)
        self.toolbar.setObjectName("toolbar-tools")
        window.addToolBar(self.toolbar)
        self.menu = window.menuBar().addMenu("&Tools")
        self.group = QActionGroup(window)
        self.group.setExclusionPolicy(QActionGroup.ExclusionPolicy.ExclusiveOptional)
        #: Tool name -> its checkable action (toolbar and menu).
        self.actions: dict[str, QAction] = {}
        #: "tool.command" -> the command's action (menu entry, button, shortcut).
        self.command_actions: dict[str, QAction] = {}
        self._command_specs: list[CommandSpec] = []
        self._commands_separator: Any = None
        #: The active tool's settings and command buttons.
        self.options = ToolOptionsBar(window)
        # A row of its own: the settings and buttons of any tool fit without overflowing
        # into the toolbar's extension menu.
        window.addToolBarBreak()
        window.addToolBar(self.options)
        self.options.settingEdited.connect(self._setting_edited)
        self.refresh()

    def frame_drawn(self) -> None:
        """A frame was drawn: the tool asked for (if any) is active now."""
        self._activating = None

    def labels(self) -> dict[str, str]:
        """Name -> label of the enabled tool plugins' tools (loading them; a plugin that fails
        to load is disabled and reported)."""
        try:
            return {c.name: c.label or c.name for c in self.plugins.registry.contributions("tool")}
        except Exception as exc:
            log.exception("loading tools failed")
            self.errors.notify(f"loading tools failed: {exc}")
            return {}

    def commands(self) -> list[CommandSpec]:
        """The commands the enabled tools declare in their manifests (the plugin whose tool
        the registry uses for each name)."""
        try:
            loaded = self.plugins.registry.contributions("tool")
        except Exception:  # noqa: BLE001  reported by labels
            return []
        specs: list[CommandSpec] = []
        for lc in loaded:
            manifest = self.plugins.registry.get(lc.plugin).manifest
            if manifest is None:
                continue
            for cmd in manifest.contribution(lc.name).commands:
                specs.append(CommandSpec(lc.plugin, lc.name, cmd))
        return specs

    def refresh(self) -> None:
        """Rebuild the tool and command actions from the enabled tool plugins."""
        labels = self.labels()
        specs = self.commands()
        if set(labels) != set(self.actions) or specs != self._command_specs:
            self._remove_actions()
            first = self.toolbar.actions()[0] if self.toolbar.actions() else None
            for name, label in labels.items():
                act = QAction(label, self.window)
                act.setCheckable(True)
                act.setObjectName(f"tool-{name}")
                act.triggered.connect(lambda checked, n=name: self.set_tool(n if checked else None))
                self.group.addAction(act)
                self.toolbar.insertAction(first, act)
                self.menu.addAction(act)
                self.actions[name] = act
            self._command_specs = specs
            self._build_command_actions(specs)
            for name, label in labels.items():
                keys = [
                    f"{a.shortcut().toString()}: {a.text()}"
                    for k, a in self.command_actions.items()
                    if k.startswith(f"{name}.") and not a.shortcut().isEmpty()
                ]
                tip = label + (f" ({', '.join(keys)})" if keys else "")
                self.actions[name].setToolTip(tip + "; Escape leaves the tool")
        self.menu.setEnabled(bool(self.actions))
        self.sync()

    def _remove_actions(self) -> None:
        self.options.show_tool(None)
        for act in self.actions.values():
            self.group.removeAction(act)
            self.toolbar.removeAction(act)
            self.menu.removeAction(act)
            act.deleteLater()
        for act in self.command_actions.values():
            self.menu.removeAction(act)
            self.window.removeAction(act)
            act.setShortcut(QKeySequence())  # it lingers until deleted: free its key now
            act.deleteLater()
        if self._commands_separator is not None:
            self.menu.removeAction(self._commands_separator)
            self._commands_separator = None
        self.actions = {}
        self.command_actions = {}

    def _build_command_actions(self, specs: list[CommandSpec]) -> None:
        """One action per declared command: in the Tools menu, on the window (so its shortcut
        works with any tool, or none, active) and as a button in the Tool options bar while
        its tool is active. A shortcut another action or the navigation already uses is
        dropped with a one-line notice; the command keeps working from its button."""
        plugin_actions = set(self.actions.values())
        others = self.window.findChildren(QAction)
        taken = reserved_shortcuts(a for a in others if a not in plugin_actions and a.isVisible())
        tools = self.plugins.registry.tools() if specs else {}
        self._commands_separator = self.menu.addSeparator() if specs else None
        for spec in specs:
            cmd = spec.command
            tool = tools.get(spec.tool)
            if not callable(getattr(tool, cmd.method, None)):
                self._warn_command(
                    spec, f"names no method {cmd.method}() of the tool; command left out"
                )
                continue
            act = QAction(cmd.label, self.window)
            act.setObjectName(f"command-{spec.key}")
            tip = f"{cmd.label} ({self.actions[spec.tool].text()})"
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
            self.window.addAction(act)  # the shortcut works whichever tool is active
            self.menu.addAction(act)
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
        self.sync()
        self.globe.request_frame()
        return True

    def _setting_edited(self, name: str, value: object) -> None:
        """A control of the Tool options bar changed: configure the active tool (persisted
        by the registry, like provider settings) and redraw."""
        tool = self.globe.active_tool()
        if tool is None:
            return
        values = dict(getattr(tool, "values", {}) or {})
        values[name] = value
        self.plugins.registry.configure(tool, values)
        self.plugins.after_frame()
        self.sync()
        self.globe.request_frame()

    def active_tool_name(self) -> str | None:
        """The model's active tool, or None."""
        if self.globe.scene is None:
            return None
        return self.model.tool if self.globe.active_tool() is not None else None

    def set_tool(self, name: str | None) -> bool:
        """Activate a tool (None: none); returns whether it is the model's tool now. The
        toolbar, menu and options bar follow the model's ``tool`` event; a tool that fails
        to activate is reported there (`model_tool_changed`)."""
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

    def model_tool_changed(self, *_args: object) -> None:
        """The model's tool changed (a toolbar click, a command, code, Escape, or its plugin
        failed): check its action and show its options. A tool asked for here that the model
        drops before a frame was drawn with it failed to activate: say why."""
        wanted = self._activating
        if self.model.tool is None and wanted is not None:
            self._report_activation_failure(wanted)
        self.sync()

    def _report_activation_failure(self, name: str) -> None:
        self._activating = None
        why = self.plugins.failure_reason("tool", name)
        if not why and self.plugins.registry.find("tool", name) is not None:
            return  # deactivated, not failed
        self.errors.notify(f"tool {name} could not be activated" + (f": {why}" if why else ""))
        self.plugins.reported("tool", name)  # one line: refresh does not repeat the failure
        self.plugins.refresh()

    def sync(self, *_args: object) -> None:
        """Check the active tool's action; show its settings and commands (or hide them)."""
        active = self.active_tool_name()
        for name, act in self.actions.items():
            act.blockSignals(True)
            act.setChecked(name == active)
            act.blockSignals(False)
        tool = self.globe.active_tool() if active is not None else None
        act = self.actions.get(active or "")
        commands = [
            a for k, a in self.command_actions.items() if active and k.startswith(f"{active}.")
        ]
        self.options.show_tool(active, tool, act.text() if act else "", commands)

    def key_unhandled(self, key: int, modifiers: object) -> None:
        """A key the active tool and navigation left: try the tool actions' shortcuts."""
        try:
            seq = QKeySequence(QKeyCombination(Qt.KeyboardModifier(modifiers), Qt.Key(key)))
        except (TypeError, ValueError):
            return
        for act in [*self.actions.values(), *self.command_actions.values()]:
            if not act.shortcut().isEmpty() and act.shortcut().matches(seq) == (
                QKeySequence.SequenceMatch.ExactMatch
            ):
                act.trigger()
                return
