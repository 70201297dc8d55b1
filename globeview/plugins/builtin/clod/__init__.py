"""Quadtree continuous LOD (Lindstrom/Ulrich as in Wang's thesis): per-vertex errors, vertex
dependencies for crack-free meshes, inside tiles chosen by the shared traversal with the
screen-space-error policy (chunked-sse's)."""
