"""`SettingEditor` (the control a tool or provider `Setting` becomes) against what a plugin
or a hand-edited settings file may hand it: huge or inverted bounds, values out of range or of
the wrong type, a default not among the choices. Each shows something valid and emits only
values the Setting accepts; nothing raises."""

from __future__ import annotations

import math

import pytest

from globeview.plugins.api import Setting

pytestmark = pytest.mark.gui


def _editor(qtbot, spec: Setting, value):
    from globeview.ui.setting_editor import SettingEditor

    w = SettingEditor(spec, value)
    qtbot.addWidget(w)
    seen: list = []
    w.edited.connect(seen.append)
    return w, seen


def test_bounded_float_slider_and_box_stay_in_step(qtbot) -> None:
    w, seen = _editor(qtbot, Setting("r", "float", 0.2, min=0.01, max=1.0), 0.2)
    assert w.slider is not None and w.spin.decimals() >= 3
    assert not seen  # showing the value is not an edit
    w.slider.setValue(w.slider.maximum())
    assert seen[-1] == pytest.approx(1.0) and w.value() == pytest.approx(1.0)
    w.spin.setValue(0.5)
    assert seen[-1] == pytest.approx(0.5)
    assert w.slider.value() == round((0.5 - 0.01) / 0.99 * w.slider.maximum())


def test_wide_int_range_gets_a_slider_too(qtbot) -> None:
    """docs/plugins.md's table: an int with both bounds is a slider and a spin box, whatever
    its span (issue #29 item 10: a span over 100 000 got a spin box alone). The slider then
    steps through the range in proportion; the box stays exact and whole."""
    w, seen = _editor(qtbot, Setting("max_tiles", "int", 20000, min=1, max=1_000_000), 20000)
    assert w.slider is not None and w.spin is not None
    w.slider.setValue(w.slider.maximum())
    assert seen[-1] == 1_000_000 and isinstance(seen[-1], int)
    w.slider.setValue(w.slider.minimum())
    assert seen[-1] == 1 and w.value() == 1
    w.spin.setValue(500_001)
    assert seen[-1] == 500_001  # the box is exact; the slider shows about where it is
    assert abs(w.slider.value() / w.slider.maximum() - 0.5) < 0.01
    w.slider.setValue(w.slider.maximum() // 4)
    assert isinstance(seen[-1], int) and abs(seen[-1] - 250_000) < 1_000


def test_dragging_an_int_slider_sets_a_whole_value(qtbot) -> None:
    """A narrow int range (a position per value): moving its slider handed the int spin box a
    float, which PyQt6 refuses with a TypeError in a slot (the process aborted)."""
    w, seen = _editor(qtbot, Setting("n", "int", 5, min=1, max=9), 5)
    w.slider.setValue(2)
    assert seen == [3] and w.value() == 3 and isinstance(seen[0], int)


@pytest.mark.parametrize(
    ("spec", "value", "shown"),
    [
        # An unbounded int with a stored 1e20: cut to what a spin box holds, no OverflowError.
        (Setting("n", "int", 1), 10**20, 2**31 - 1),
        (Setting("n", "int", 1, min=-1e30, max=1e30), -(10**25), -(2**31)),
        # Out of range: clamped by the Setting.
        (Setting("n", "int", 5, min=1, max=9), 50, 9),
        # Garbage: the default.
        (Setting("x", "float", 2.5, min=0.0, max=10.0), "lots", 2.5),
        (Setting("x", "float", 2.5, min=0.0, max=10.0), math.nan, 2.5),
        (Setting("x", "float", 2.5), math.inf, 2.5),
        # Inverted bounds: no slider, nothing raises.
        (Setting("x", "float", 1.0, min=5.0, max=1.0), 3.0, None),
        (Setting("flag", "bool", False), "yes", True),
        # A plugin's own default is garbage: a neutral value of the type.
        (Setting("f", "float", "abc"), "x", 0.0),
        (Setting("i", "int", None, min=2, max=3), None, 2),
        (Setting("c", "choice", "a"), "a", ""),
        # A type the UI has no editor for: shown, not editable, nothing raises.
        (Setting("s", "string", "abc"), "abc", "abc"),  # type: ignore[arg-type]
    ],
)
def test_hostile_values_show_something_valid(qtbot, spec, value, shown) -> None:
    w, seen = _editor(qtbot, spec, value)
    if shown is not None:
        assert w.value() == shown
    if spec.min is not None and spec.max is not None and spec.max < spec.min:
        assert w.slider is None
    assert not seen


def test_choice_default_not_offered_and_edits_emit_valid_values(qtbot) -> None:
    w, seen = _editor(qtbot, Setting("c", "choice", "green", choices=("red", "blue")), "green")
    assert w.value() in ("red", "blue")
    w.combo.setCurrentText("blue")
    assert seen == ["blue"]
    w.setValue("purple")  # not a choice: the default is shown, and what is shown is sent
    assert seen[-1] in ("red", "blue")
