"""User-facing errors shared by every layer.

A `GlobeviewError` carries a one-line message meant for a person: the CLI prints it without a
traceback and exits non-zero, the GUI shows it in a dialog. Everything else that escapes is a
bug and keeps its traceback.
"""


class GlobeviewError(Exception):
    """An error caused by the user's input or environment, explained in one line."""


class SettingError(GlobeviewError, ValueError):
    """A setting given a value outside its range (a display setting such as exaggeration):
    one line naming it and the range. Also a ValueError, as `globeview.validate` raises."""


class DemError(GlobeviewError):
    """A raster cannot be used as a DEM (unreadable, no CRS, all nodata, ...)."""


class StoreError(GlobeviewError):
    """A tile store cannot be built, opened or read."""


class PluginFailed(GlobeviewError):
    """A plugin failed where nothing can stand in for it (a layer type that cannot open the
    user's file, a tool whose plot was asked for), or any plugin under ``render --strict``:
    one line naming the plugin and its error. Not the user's input, so the command line
    exits with `exit_status` 3 instead of 2 (and writes nothing)."""

    exit_status = 3
