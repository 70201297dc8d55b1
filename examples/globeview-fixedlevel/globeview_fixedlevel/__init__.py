"""Example globeview plugin: `FixedLevelProvider` (LOD) and `MarkerTool` (tool).

Kept free of imports so that nothing runs before globeview asks for a contribution.
"""

__version__ = "0.1.0"
