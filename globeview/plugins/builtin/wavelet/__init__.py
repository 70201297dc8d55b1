"""Wavelet LOD (Zhang et al.): levels chosen from static (roughness) and dynamic (distance)
error over the wavelet pyramid."""
