"""Terrain: DEM readers, the ellipsoidal quadtree, wavelet pyramids and the tile store.

numpy/rasterio/pywt only: no Qt, no GL.
"""
