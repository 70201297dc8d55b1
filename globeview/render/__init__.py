"""Rendering with moderngl: camera, tile meshes, shaders, culling, picking, offscreen frames."""
