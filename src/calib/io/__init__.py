"""Files: the recording format ``calib-recording-1`` (``recording``), netCDF writing and provenance (``netcdf``)
and the one atomic writer (``atomic``). The only layer that opens files for writing."""

#: the formats ``calib export`` writes (:mod:`calib.io.export_formats`); here so that the command line lists them
#: without loading the netCDF and array libraries
EXPORT_FORMATS = ("imutk", "imucal", "json")
