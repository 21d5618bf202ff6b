"""Files: the recording format ``calib-recording-1`` (``recording``, its API; implemented by ``header``,
``validation``, ``validation_cache``, ``chunked_reading``, ``in_memory`` and ``writing``), netCDF writing and
provenance (``netcdf``), the one atomic writer (``atomic``) and the export formats (``export_formats``). The only
layer that opens files for writing."""

#: the formats ``calib export`` writes (:mod:`calib.io.export_formats`); here so that the command line lists them
#: without loading the netCDF and array libraries
EXPORT_FORMATS = ("imutk", "imucal", "json")
