"""Moved to `globeview.app.testing` (the application layer): the pytest fixtures for plugin
authors, which the ``pytest11`` entry point ``globeview`` loads from there, and the helpers
beside them.

Kept as a name because docs/plugins.md told plugin authors to import ``render_frame`` (and
the helpers with it) from here before API 1.3; new code imports `globeview.app.testing`.
The one import of the application layer under `globeview.plugins`, allowed by name in the
import contracts (pyproject.toml).
"""

from globeview.app.testing import (
    PluginSite,
    RenderedFrame,
    make_view,
    plugin_manifest,
    render_frame,
)

__all__ = ["PluginSite", "RenderedFrame", "make_view", "plugin_manifest", "render_frame"]
