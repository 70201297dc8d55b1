"""Which layer of a multi-layer GIS vector file to open (a GeoPackage's tables, a KML's
folders): a modal list of the file's layers with their geometry types."""

from __future__ import annotations

from PyQt6.QtWidgets import QInputDialog, QWidget

__all__ = ["ask_vector_layer"]


def ask_vector_layer(
    parent: QWidget | None, file_name: str, layers: list[tuple[str, str]]
) -> str | None:
    """The layer the user picks among ``layers`` ((name, geometry type) rows) of
    ``file_name``, or None when cancelled."""
    items = [f"{name}  ({kind})" for name, kind in layers]
    text, ok = QInputDialog.getItem(
        parent, "Open layer", f"{file_name} has {len(layers)} layers; open:", items, 0, False
    )
    if not ok or text not in items:
        return None
    return layers[items.index(text)][0]
