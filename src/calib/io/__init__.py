"""Files: the recording format ``calib-recording-1`` (``recording``), netCDF writing and provenance (``netcdf``)
and the one atomic writer (``atomic``). The only layer that opens files for writing."""
