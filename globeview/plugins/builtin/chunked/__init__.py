"""Chunked LOD (Agrawal et al., TREND; Cesium's traversal): refine quadtree tiles until their
screen-space error is below tau pixels."""
