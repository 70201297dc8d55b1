"""Example globeview plugin with all three kinds of contribution: `FixedLevelProvider` and
`CappedProvider` (LOD, provider.py), `MarkerTool` (tool, marker.py) and
`GraticuleLayerType` (layer, graticule.py), written against `globeview.plugins.api` only.

Kept free of imports so that nothing runs before globeview asks for a contribution.
"""

__version__ = "0.1.0"
