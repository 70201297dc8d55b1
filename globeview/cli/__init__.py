"""The `globeview` command line.

Each subcommand lives in its own module with ``add_arguments(parser)`` and ``run(args)``.
Those modules import only argparse at top level and the heavy layers inside ``run``, so
`globeview info` never loads GL or Qt.

Whatever goes wrong, a command ends with at most one line on stderr (issue #13):

- bad input (arguments, files, outputs): ``globeview: error: ...``, exit 2 — a
  `GlobeviewError` raised where the cause is known, or argparse's own complaint;
- a plugin failure nothing stands in for (`PluginFailed`, e.g. a layer type crashing on a
  ``--layer`` file), or any plugin failure under ``render --strict``: ``globeview: error:
  ...`` naming the plugin and its error, exit 3, nothing written;
- out of memory: ``globeview: error: out of memory while running COMMAND ...``, exit 2;
- a bug: ``globeview: internal error: Type: message (details in LOG)``, exit 1, with the
  traceback and the recent log records written to LOG; ``GLOBEVIEW_DEBUG=1`` re-raises
  instead (full traceback) and lets library messages through;
- GDAL/PROJ/rasterio chatter never reaches stderr (`quiet_libraries`); warnings from
  globeview's own loggers are shown as one ``globeview: warning: ...`` line each.
"""

from __future__ import annotations

import argparse
import errno
import importlib
import logging
import os
import sys
from collections import deque
from pathlib import Path
from typing import NoReturn

from globeview import __version__
from globeview.errors import GlobeviewError
from globeview.paths import log_path

# subcommand name -> module under globeview.cli, with a one-line help
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "info": ("info", "describe DEM rasters (bounds, resolution, nodata, value range)"),
    "ingest": ("ingest", "build a tile-pyramid store from one or more DEMs"),
    "render": ("render", "render the globe headless to a PNG (EGL, no display needed)"),
    "height": ("height", "heights of the terrain at points: ellipsoidal, geoid, orthometric"),
    "plugins": ("plugins", "list, validate, enable and disable plugins"),
    "bench": ("bench", "benchmarks: camera flights, the papers' experiments, budgets, soak"),
    "gui": (
        "gui",
        "open the desktop window on DEMs, stores and overlay files, optionally on a --camera "
        "view with a --lod, a --tool and --set settings (the default with no subcommand)",
    ),
}

#: Options whose value is a comma-separated list of numbers, which may start with '-'
#: (``--camera -71,44,9000``); see `join_negative_values`.
NUMERIC_LIST_OPTIONS = ("--camera", "--collapse", "--background", "--point")
#: Options whose value is ';'-separated lists of numbers (``--points -71,44;-70,45``).
POINT_LIST_OPTIONS = ("--points",)
#: Options taking one number that may be negative.
NUMERIC_OPTIONS = ("--tau", "--fov", "--exaggeration", "--fps", "--frames")

#: OS errors that come from the user's environment (exit 2, one line), not from a bug.
_ENVIRONMENT_ERRNOS = frozenset(
    {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EMFILE}
)
DEBUG_ENV = "GLOBEVIEW_DEBUG"


class OneLineParser(argparse.ArgumentParser):
    """argparse whose errors are one line (``globeview: error: ...``, exit 2) instead of the
    usage block plus the message; ``--help`` still prints the full usage."""

    def error(self, message: str) -> NoReturn:
        hint = f"; see `{self.prog} --help`"
        print(f"globeview: error: {message}{hint}", file=sys.stderr)
        sys.exit(2)


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="globeview",
        description="A desktop virtual globe for terrain. With no subcommand, opens the window. "
        "`globeview FILE...` opens the window with those DEMs or stores.",
    )
    parser.add_argument("--version", action="version", version=f"globeview {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=OneLineParser)
    for name, (module, help_text) in SUBCOMMANDS.items():
        mod = importlib.import_module(f"globeview.cli.{module}")
        p = sub.add_parser(name, help=help_text, description=help_text)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


# -- argv preprocessing -----------------------------------------------------------------------
def _is_number_list(text: str) -> bool:
    parts = text.split(",")
    try:
        [float(p) for p in parts]
    except ValueError:
        return False
    return bool(parts)


def join_negative_values(argv: list[str]) -> list[str]:
    """``--camera -71,44,9000`` -> ``--camera=-71,44,9000``: argparse takes a value starting
    with '-' for an option unless it looks like a plain negative number, so a list of numbers
    after a numeric option is joined to it (a value that parses as numbers is a value)."""
    out: list[str] = []
    i = 0
    while i < len(argv):
        tok = argv[i]
        nxt = argv[i + 1] if i + 1 < len(argv) else None
        if tok == "--":
            out.extend(argv[i:])
            break
        if (
            nxt is not None
            and nxt.startswith("-")
            and (
                (tok in NUMERIC_LIST_OPTIONS and _is_number_list(nxt))
                or (tok in POINT_LIST_OPTIONS and _is_number_list(nxt.replace(";", ",")))
                or (tok in NUMERIC_OPTIONS and _is_number_list(nxt) and "," not in nxt)
            )
        ):
            out.append(f"{tok}={nxt}")
            i += 2
            continue
        out.append(tok)
        i += 1
    return out


#: The window's options (`globeview gui`, cli/view_options.py): a command line starting with
#: one of them, ``globeview --camera ...``, opens the window as ``globeview gui --camera ...``.
GUI_OPTIONS = ("--camera", "--lod", "--tool", "--set")


def route_bare_files(argv: list[str]) -> list[str]:
    """``globeview FILE...`` (what ``./run FILE`` does) means ``globeview gui FILE...``: a
    first argument that is not a subcommand nor an option, and exists as a path or looks like
    a file name (has a suffix or a slash), opens the window with it; so does a first
    argument that is one of the window's options (`GUI_OPTIONS`)."""
    if not argv:
        return argv
    first = argv[0]
    if first.split("=", 1)[0] in GUI_OPTIONS:
        return ["gui", *argv]
    if first in SUBCOMMANDS or first.startswith("-"):
        return argv
    if os.path.exists(first) or Path(first).suffix or os.sep in first:
        return ["gui", *argv]
    return argv


# -- quiet libraries and the log ----------------------------------------------------------------
class _CliLog(logging.Handler):
    """The CLI's only log handler: keeps the recent records of every logger (GDAL, rasterio,
    pyproj, warnings...) in memory for the internal-error log, and shows warnings of
    globeview's own loggers as one stderr line each."""

    def __init__(self, echo_all: bool) -> None:
        super().__init__(logging.DEBUG)
        self.records: deque[str] = deque(maxlen=400)
        self.echo_all = echo_all
        self.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self.records.append(self.format(record))
            ours = record.name == "globeview" or record.name.startswith("globeview.")
            if self.echo_all or (ours and record.levelno >= logging.WARNING):
                first = (record.getMessage().strip().splitlines() or [""])[0]
                print(f"globeview: {record.levelname.lower()}: {first}", file=sys.stderr)
        except Exception:  # noqa: BLE001  a log record must never take the command down
            pass


_handler: _CliLog | None = None


def quiet_libraries(debug: bool = False) -> _CliLog:
    """Keep GDAL, PROJ, rasterio, pyproj and Python warnings off stderr for the rest of the
    process; their records are kept for the internal-error log instead. Idempotent.

    GDAL's default error handler prints ``ERROR 1: PROJ: ...`` straight to stderr when no
    rasterio environment is active; ``CPL_LOG`` sends it to a file instead (read by GDAL when
    it first reports, so this must run before any GDAL call). Inside a rasterio environment
    GDAL messages become ``rasterio._err``/``rasterio._env`` log records, and pyproj logs to
    ``pyproj``: the root handler here catches them all (Python's last-resort handler would
    print them otherwise). With ``debug`` (``GLOBEVIEW_DEBUG=1``) everything is shown.
    """
    global _handler
    if not debug:
        os.environ["CPL_LOG"] = os.devnull
        os.environ["CPL_DEBUG"] = "OFF"
        os.environ.setdefault("PROJ_DEBUG", "0")
    if _handler is None:
        _handler = _CliLog(echo_all=debug)
        root = logging.getLogger()
        root.addHandler(_handler)
        root.setLevel(logging.DEBUG if debug else logging.INFO)
        logging.captureWarnings(True)
    return _handler


def write_error_log(argv: list[str], exc: BaseException) -> Path | None:
    """Append the traceback of ``exc`` and the recent log records to the log file (falling
    back to the temp folder when the cache is not writable); returns where, or None."""
    import tempfile
    import time
    import traceback

    text = [
        f"==== {time.strftime('%Y-%m-%d %H:%M:%S')} globeview {__version__}: "
        f"globeview {' '.join(argv)}",
        *(_handler.records if _handler is not None else ()),
        "".join(traceback.format_exception(exc)),
    ]
    for path in (log_path(), Path(tempfile.gettempdir()) / f"globeview-{os.getuid()}.log"):
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            with open(path, "a", encoding="utf-8") as f:
                f.write("\n".join(text) + "\n")
            return path
        except OSError:
            continue
    return None


def _one_line(text: str) -> str:
    return " ".join(str(text).split()) or "(no message)"


# -- the entry point ----------------------------------------------------------------------------
def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = os.environ.get(DEBUG_ENV, "") not in ("", "0")
    command = "globeview"
    try:  # parsing too: Ctrl-C while the subcommand modules import is still one line
        quiet_libraries(debug)
        argv = route_bare_files(join_negative_values(argv))
        parser = build_parser()
        args = parser.parse_args(argv)
        if args.command is None:
            args = parser.parse_args(["gui", *argv])
        command = f"globeview {args.command}"
        return int(args._run(args) or 0)
    except GlobeviewError as exc:
        print(f"globeview: error: {_one_line(str(exc))}", file=sys.stderr)
        # 2: the user's input; a subclass may say otherwise (PluginFailed: 3).
        return int(getattr(exc, "exit_status", 2))
    except KeyboardInterrupt:
        print("globeview: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # Output piped into a reader that closed early (e.g. `| head`): not an error.
        sys.stderr.close()
        return 0
    except MemoryError:
        if debug:
            raise
        print(
            f"globeview: error: out of memory while running `{command}` "
            "(try a smaller --size, fewer or smaller DEMs)",
            file=sys.stderr,
        )
        return 2
    except (SystemExit, GeneratorExit):
        raise
    except OSError as exc:
        # The environment, not a bug: a full disk, a read-only mount or a permission met
        # somewhere no cause-specific check caught it.
        if debug or exc.errno not in _ENVIRONMENT_ERRNOS:
            return _internal_error(argv, exc, debug)
        where = f": {exc.filename}" if exc.filename else ""
        print(f"globeview: error: {exc.strerror}{where}", file=sys.stderr)
        return 2
    except Exception as exc:  # noqa: BLE001  last resort: a bug is one line plus the log (exit 1)
        return _internal_error(argv, exc, debug)


def _internal_error(argv: list[str], exc: Exception, debug: bool) -> int:
    """The last line of defence, for a bug: one line on stderr, the traceback in the log
    (`write_error_log`), exit 1. With ``GLOBEVIEW_DEBUG=1`` the exception propagates."""
    if debug:
        raise exc
    where = write_error_log(argv, exc)
    detail = f"details in {where}" if where else f"set {DEBUG_ENV}=1 for the traceback"
    print(
        f"globeview: internal error: {type(exc).__name__}: {_one_line(str(exc))[:300]} ({detail})",
        file=sys.stderr,
    )
    return 1
