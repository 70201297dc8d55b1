"""Ingest: DEM files into a tile store (`driver.ingest`), as a Dask graph (`schedule`,
`tasks`), incremental updates (`update`), the pyramid's kernels (`wavelet`, `tile_errors`,
`mband`)."""
