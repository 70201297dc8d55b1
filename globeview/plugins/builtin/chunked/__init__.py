"""Chunked LOD (Agrawal et al., TREND; Cesium's traversal): refine quadtree tiles until their
screen-space error is below tau pixels - the screen-space-error policy on the shared
traversal (globeview.lod)."""
