"""`SettingEditor`: the widget the window builds for one plugin `Setting`, for LOD providers
(the plugin panel) and tools (the tool options bar) alike.

- ``bool``: a check box;
- ``choice``: a combo box of the choices;
- ``int`` / ``float`` with both bounds: a slider and a spin box kept in step (the slider for
  a quick drag, the box for an exact value); an int whose span is at most
  ``MAX_INT_SLIDER_SPAN`` has a slider position per value, a wider one (and a float)
  ``SLIDER_STEPS`` positions across the range, rounded to a whole value;
- ``int`` / ``float`` without both bounds: a spin box alone;
- any other type: a disabled label showing the value (nothing to edit, nothing raises).

``edited(object)`` carries the new value, coerced by the Setting (type, bounds), only for
user edits and `setValue`; `show_value` updates the display silently.
"""

from __future__ import annotations

import math
from typing import Any

from PyQt6.QtCore import Qt, pyqtSignal
from PyQt6.QtWidgets import (
    QCheckBox,
    QComboBox,
    QDoubleSpinBox,
    QHBoxLayout,
    QLabel,
    QSlider,
    QSpinBox,
    QWidget,
)

from globeview.plugins.api import Setting

#: Slider positions across a bounded float setting's range (and a wide int one's).
SLIDER_STEPS = 1000
#: Widest int range given one slider position per value; a wider one gets `SLIDER_STEPS`.
MAX_INT_SLIDER_SPAN = 100_000


class SettingEditor(QWidget):
    """An editor for one `Setting` showing ``value`` (see the module docstring).

    Attributes (whichever the type uses, else None): ``check``, ``combo``, ``slider``,
    ``spin``.
    """

    edited = pyqtSignal(object)

    def __init__(self, spec: Setting, value: Any, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.spec = spec
        self.check: QCheckBox | None = None
        self.combo: QComboBox | None = None
        self.slider: QSlider | None = None
        self.spin: QSpinBox | QDoubleSpinBox | None = None
        self.label: QLabel | None = None
        self._raw: Any = value  # what was given, for a type with no editor
        self._quiet = False
        lay = QHBoxLayout(self)
        lay.setContentsMargins(0, 0, 0, 0)
        if spec.type == "bool":
            self.check = QCheckBox(spec.label or spec.name)
            self.check.toggled.connect(self._user_edit)
            lay.addWidget(self.check)
        elif spec.type == "choice":
            self.combo = QComboBox()
            self.combo.addItems([str(c) for c in spec.choices])
            self.combo.currentTextChanged.connect(self._user_edit)
            lay.addWidget(self.combo)
        elif spec.type in ("int", "float"):
            self._build_number(lay)
        else:
            self.label = QLabel(_clip(repr(value)))
            self.label.setEnabled(False)
            lay.addWidget(self.label)
        self.setToolTip(spec.help)
        self.show_value(value)

    def _build_number(self, lay: QHBoxLayout) -> None:
        spec = self.spec
        lo = _finite(spec.min)
        hi = _finite(spec.max)
        if spec.type == "int":
            spin: QSpinBox | QDoubleSpinBox = QSpinBox()
            # A QSpinBox holds a C int: wider bounds (or none) are cut to its range.
            spin.setRange(
                _c_int(lo if lo is not None else -math.inf),
                _c_int(hi if hi is not None else math.inf),
            )
        else:
            spin = QDoubleSpinBox()
            spin.setDecimals(_decimals(lo, hi))
            spin.setRange(lo if lo is not None else -1e12, hi if hi is not None else 1e12)
            spin.setSingleStep(_step(lo, hi))
        self.spin = spin
        if lo is not None and hi is not None and hi > lo:
            # Every bounded number gets a slider (docs/plugins.md's table); a wide int range
            # steps through it in proportion, as a float's does (the box stays exact).
            self.slider = QSlider(Qt.Orientation.Horizontal)
            self.slider.setRange(0, int(hi - lo) if self._int_per_value() else SLIDER_STEPS)
            self.slider.setMinimumWidth(90)
            self.slider.valueChanged.connect(self._slider_moved)
            lay.addWidget(self.slider, 1)
        spin.valueChanged.connect(self._user_edit)
        lay.addWidget(spin)

    # -- value -------------------------------------------------------------------------------
    def value(self) -> Any:
        """The value shown, in the Setting's type."""
        if self.check is not None:
            return self.check.isChecked()
        if self.combo is not None:
            return self.combo.currentText()
        if self.spin is None:
            return self._raw
        v = self.spin.value()
        return int(v) if self.spec.type == "int" else float(v)

    def show_value(self, value: Any) -> None:
        """Display ``value`` (coerced; an invalid one shows the default, an invalid default a
        neutral value) without emitting."""
        self._raw = value
        value = self._valid(value)
        self._quiet = True
        try:
            if self.check is not None:
                self.check.setChecked(bool(value))
            elif self.combo is not None:
                self.combo.setCurrentText(str(value))
            elif self.spin is not None:
                # Within the box's range (a stored 1e20 for an unbounded int must not
                # overflow the C int behind a QSpinBox).
                v = min(max(float(value), self.spin.minimum()), self.spin.maximum())
                self.spin.setValue(int(v) if self.spec.type == "int" else v)  # type: ignore[arg-type]
                self._sync_slider()
        finally:
            self._quiet = False

    def setValue(self, value: Any) -> None:  # Qt spelling, as on a spin box
        """Set ``value`` as a user edit would (emits ``edited``)."""
        self.show_value(value)
        self._user_edit()

    # -- internals ----------------------------------------------------------------------------
    def _valid(self, value: Any) -> Any:
        """``value`` coerced by the Setting, else its default coerced, else a neutral value
        of the type (a plugin's own default may be garbage too)."""
        for candidate in (value, self.spec.default):
            try:
                return self.spec.coerce(candidate)
            except (TypeError, ValueError, OverflowError):
                continue
        if self.spec.type == "choice":
            return str(self.spec.choices[0]) if self.spec.choices else ""
        if self.spin is not None:
            return min(max(0, self.spin.minimum()), self.spin.maximum())
        return False if self.spec.type == "bool" else value

    def _int_per_value(self) -> bool:
        """Whether the slider has one position per value (a bounded int of a narrow span)."""
        lo, hi = _finite(self.spec.min), _finite(self.spec.max)
        return (
            self.spec.type == "int"
            and lo is not None
            and hi is not None
            and hi - lo <= MAX_INT_SLIDER_SPAN
        )

    def _to_slider(self, v: float) -> int:
        lo, hi = float(self.spec.min), float(self.spec.max)  # type: ignore[arg-type]
        if self._int_per_value():
            return round(v - lo)
        return round((v - lo) / (hi - lo) * SLIDER_STEPS)

    def _from_slider(self, pos: int) -> float:
        lo, hi = float(self.spec.min), float(self.spec.max)  # type: ignore[arg-type]
        if self._int_per_value():
            return lo + pos
        return lo + (hi - lo) * pos / SLIDER_STEPS

    def _sync_slider(self) -> None:
        if self.slider is None or self.spin is None:
            return
        self.slider.blockSignals(True)
        self.slider.setValue(self._to_slider(float(self.spin.value())))
        self.slider.blockSignals(False)

    def _slider_moved(self, pos: int) -> None:
        if self.spin is None:
            return
        # The spin box rounds to its decimals (an int box takes whole values only); its
        # valueChanged then reports the edit.
        v = self._from_slider(pos)
        if isinstance(self.spin, QSpinBox):
            self.spin.setValue(round(v))
        else:
            self.spin.setValue(v)

    def _user_edit(self, *_args: Any) -> None:
        if self.slider is not None and not self.slider.isSliderDown():
            self._sync_slider()
        if self._quiet:
            return
        self.edited.emit(self.value())


def _finite(bound: float | None) -> float | None:
    if bound is None:
        return None
    try:
        b = float(bound)
    except (TypeError, ValueError):
        return None
    return b if math.isfinite(b) else None


def _clip(text: str, limit: int = 40) -> str:
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _c_int(bound: float) -> int:
    """``bound`` cut to the range of a C int (what a QSpinBox holds)."""
    return int(min(max(bound, -(2**31)), 2**31 - 1))


def _decimals(lo: float | None, hi: float | None) -> int:
    """Decimals for a float spin box: enough to show one slider step of the range."""
    if lo is None or hi is None or hi <= lo:
        return 3
    return min(max(2, math.ceil(-math.log10((hi - lo) / SLIDER_STEPS))), 8)


def _step(lo: float | None, hi: float | None) -> float:
    """The spin box's arrow step: a hundredth of the range (0.1 unbounded)."""
    if lo is None or hi is None or hi <= lo:
        return 0.1
    return 10.0 ** math.floor(math.log10((hi - lo) / 100.0))
