"""benchmarks/bench_launch.py's reading of the polled screen (issue #27): when the globe counts
as drawn, when the screen settled, the verdict line; and its Xvfb framebuffer read back as
the pixels drawn. No timing is asserted: the figures and the target live in the script."""

from __future__ import annotations

import argparse
import importlib.util
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_launch.py"


def _bench_launch():
    spec = importlib.util.spec_from_file_location("bench_launch", SCRIPT)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules["bench_launch"] = mod  # dataclasses look their module up while decorating
    spec.loader.exec_module(mod)
    return mod


def test_drawn_is_the_first_poll_with_95_percent_of_the_final_globe() -> None:
    mod = _bench_launch()
    run = mod.Run([(0.0, 0, 0.1), (1.0, 0, 0.5), (1.5, 50, 0.8), (2.0, 96, 1.0), (3.0, 100, 1.2)])
    assert run.first_at(0.05) == (1.5, 0.8)
    assert run.first_at(0.95) == (2.0, 1.0)
    assert run.settled() == 3.0  # 96 -> 100 is a change of more than 0.5 %
    blank = mod.Run([(0.0, 0, 0.1), (1.0, 0, 0.2)])
    assert blank.first_at(0.95) is None


def test_report_says_whether_the_target_is_met() -> None:
    mod = _bench_launch()
    fast = mod.Run([(0.2, 0, 0.1), (0.8, 100, 0.7), (4.0, 100, 1.0)])
    slow = mod.Run([(0.2, 0, 0.1), (2.5, 100, 1.9), (6.0, 100, 2.0)])
    args = argparse.Namespace()
    assert "0.80 s (median of 1, range 0.80-0.80): met" in mod.report([fast], [1.0], args)
    text = mod.report([slow, slow, fast], [1.0, 1.0, 1.0], args)
    assert "| 1 | 2.50 | 2.50 | 1.90 | 2.50 | 1.0 |" in text
    assert text.endswith("2.50 s (median of 3, range 0.80-2.50): not met")


@pytest.mark.skipif(shutil.which("Xvfb") is None, reason="needs Xvfb")
def test_the_screen_is_read_from_xvfbs_framebuffer(tmp_path) -> None:
    """A blank screen has no globe pixels; a saturated rectangle drawn by an X client has
    (every STEP-th pixel of it)."""
    mod = _bench_launch()
    screen = mod.Screen(64, 48, tmp_path)
    try:
        assert screen.pixels().shape == (48 // mod.STEP, 64 // mod.STEP, 3)
        assert screen.saturated() == 0
        code = (
            "from PyQt6.QtWidgets import QApplication, QWidget\n"
            "from PyQt6.QtCore import QTimer\n"
            "app = QApplication([]); w = QWidget(); w.setStyleSheet('background: #0040ff')\n"
            "w.setGeometry(0, 0, 64, 48); w.show()\n"
            "QTimer.singleShot(1500, app.quit); app.exec()\n"
        )
        proc = subprocess.Popen(
            [sys.executable, "-c", code],
            env={"DISPLAY": screen.display, "PATH": "/usr/bin:/bin", "QT_QPA_PLATFORM": "xcb"},
        )
        seen = 0
        for _ in range(100):
            seen = max(seen, screen.saturated())
            if proc.poll() is not None:
                break
            time.sleep(0.05)
        proc.wait(30)
        assert seen > 0
    finally:
        screen.close()
