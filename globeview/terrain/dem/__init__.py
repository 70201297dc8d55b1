"""DEM sources: reading rasters window by window (`reader`), their vertical datums
(`vdatum`), the surface continued past a DEM's data edge (`edge`)."""
