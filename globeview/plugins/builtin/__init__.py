"""Built-in plugins. Each ships a TOML manifest next to its module and is registered through
globeview's own ``globeview.plugins`` entry points, exactly like a third-party plugin.

This package's ``__init__`` stays empty of imports: discovery reads the manifests from this
directory without importing any built-in plugin module.
"""
