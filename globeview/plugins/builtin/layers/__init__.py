"""The built-in layer types: imagery and thematic drapes, GeoJSON vectors and placemarks."""
