"""Where the window's launch goes: CPU seconds at each step of `globeview.ui.app.run`, in one
process, up to the first frames (issue #27's launch target; `bench_launch.py` measures the
whole launch from outside). Needs a display (run it under ``xvfb-run -s "-screen 0
1600x1000x24"``). Each mark is the process's CPU time (all threads: the tile loader's too)
since it started, so the machine's load inflates it less than wall time.

    xvfb-run -a -s "-screen 0 1600x1000x24" .venv/bin/python benchmarks/profile_launch.py
    ... benchmarks/profile_launch.py --frames 3 --profile 25   # + cProfile, top 25 by own time
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import sys
import time

MARKS: list[tuple[str, float]] = [("interpreter up", time.process_time())]
PROFILE = cProfile.Profile()


def mark(what: str) -> None:
    MARKS.append((what, time.process_time()))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=3, help="frames to wait for (default 3)")
    ap.add_argument("--profile", type=int, default=0, help="print the N top functions")
    args = ap.parse_args(argv)
    if args.profile:
        PROFILE.enable()
    from PyQt6.QtCore import QSettings, QTemporaryDir, QTimer

    import globeview.ui.app as app

    mark("import globeview.ui.app")
    qapp = app.create_application()
    tmp = QTemporaryDir()
    qsettings = QSettings(tmp.filePath("window.ini"), QSettings.Format.IniFormat)
    terrain = app.embedded_terrain()
    mark("embedded terrain (stores opened)")
    window = app.MainWindow(
        terrain, qsettings, app.plugin_registry(qsettings), embedded_overlays=True
    )
    mark("MainWindow() (docks, embedded overlays)")
    window.globe.sceneReady.connect(lambda _: mark("GL context and GlobeSession (initializeGL)"))
    seen = [0]

    def rendered(stats: object, fps: float) -> None:
        seen[0] += 1
        drawn, loading = getattr(stats, "tiles_drawn", 0), getattr(stats, "tiles_loading", 0)
        mark(f"frame {seen[0]} ({drawn} tiles drawn, {loading} loading)")
        if seen[0] == args.frames:
            PROFILE.disable()
            QTimer.singleShot(0, finish)  # not from inside the paint that emitted this

    def finish() -> None:
        window.close()  # stops the tile loader before the interpreter goes
        qapp.quit()

    window.globe.frameRendered.connect(rendered)
    window.resize(1600, 1000)
    window.show()
    QTimer.singleShot(60_000, qapp.quit)
    qapp.exec()
    report(args.profile)
    return 0 if seen[0] >= args.frames else 1


def report(top: int) -> None:
    print("| CPU s (cumulative) | + s | step |\n|---:|---:|---|")
    prev = 0.0
    for what, t in MARKS:
        print(f"| {t:.2f} | {t - prev:.2f} | {what} |")
        prev = t
    if top:
        print()
        pstats.Stats(PROFILE, stream=sys.stdout).sort_stats("tottime").print_stats(top)


if __name__ == "__main__":
    raise SystemExit(main())
