"""Composition: the visible stores as one terrain (`stack.TerrainStack`), the border blend
(`blend`), errors of tiles below a layer's data (`drawn_error`), heights at points
(`height_query`)."""
