"""User-facing errors shared by every layer.

A `GlobeviewError` carries a one-line message meant for a person: the CLI prints it without a
traceback and exits non-zero, the GUI shows it in a dialog. Everything else that escapes is a
bug and keeps its traceback.
"""


class GlobeviewError(Exception):
    """An error caused by the user's input or environment, explained in one line."""


class DemError(GlobeviewError):
    """A raster cannot be used as a DEM (unreadable, no CRS, all nodata, ...)."""


class StoreError(GlobeviewError):
    """A tile store cannot be built, opened or read."""
