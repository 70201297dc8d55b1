"""The measure tool: geodesic distance, azimuth and terrain profile between picked points."""
