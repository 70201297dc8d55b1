"""The Qt desktop shell (the only layer that imports PyQt6)."""
