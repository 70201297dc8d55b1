"""Where globeview keeps its own files: the cache folder (tile stores of opened DEMs) and the
log that internal errors and plugin failures go to.

Pure standard library, so every layer (terrain, plugins, the CLI, the window) asks here and
they all agree.
"""

from __future__ import annotations

import os
from pathlib import Path

#: The log of internal errors and plugin failures, in the cache folder.
LOG_NAME = "globeview.log"


def cache_dir() -> Path:
    """``$GLOBEVIEW_CACHE_DIR``, else ``$XDG_CACHE_HOME/globeview``, else ``~/.cache/globeview``."""
    env = os.environ.get("GLOBEVIEW_CACHE_DIR")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "globeview"


def log_path() -> Path:
    """``globeview.log`` in the cache folder: internal errors' tracebacks (CLI and window) and
    plugin failures."""
    return cache_dir() / LOG_NAME
