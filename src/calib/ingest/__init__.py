"""Import recordings made elsewhere into ``calib-recording-1`` (see :mod:`calib.io.recording`).

One module per source format (``imu_tk``, ``imucal``, ``columns``, ``mikoff``, ``npz_columns``, ``rosbag``,
``matlab``), each with
``import_<format>(settings) -> xarray.Dataset`` and its settings ``KEYS``; shared settings, checks and assembly in
``common``; the registry :data:`calib.ingest.importers.IMPORTERS` (a new format is one module plus one entry
there). :func:`import_recording` (re-exported here from ``importers``) dispatches on ``settings['format']`` and
writes atomically with :func:`calib.io.recording.write` (a failed import never leaves a file under the output
name). Settings are plain dicts, normally read from ``config/import/*.yaml`` with :func:`load_settings`.

Nothing is guessed: units, sample kind, sample rate, site latitude, axis signs and the sense of hand-made
turns come from the settings (or the file, where it says so). What *can* be checked against the data is:

* accel units: the median accel norm over the quietest quarter of the record must be within
  ``units_check_tolerance`` (default 20 %) of local gravity in the declared units (1 g = 9.80665 m s-2);
  for counts only when ``accel.approx_counts_per_g`` is given;
* gyro units: peak rate below 5000 deg/s; and for labelled turns the integrated angle about the labelled
  axis must have the declared sign and be within 25 % of the declared angle (counts: only with
  ``gyro.approx_counts_per_deg_s``);
* structure: every row complete (a short last row means a truncated file), no NaN/Inf, header names as
  declared, time strictly increasing, the two IMU-TK files sharing their timestamps row for row;
* rate: with a time column the recording's ``sample_rate_hz`` is the sample clock fitted to it
  (:func:`calib.core.clock.fit_clock`: least-squares line of time against the clock index, robust to
  burst arrival, dropped samples counted; the median step is not the rate of a bursty logger), stored with
  its uncertainty, jitter and dropped-sample count as ``clock_*`` attributes; a declared ``sample_rate_hz``
  must agree within max(5 sigma, 1e-3 relative). Without a time column the declared rate is the rate;
* clock: jitter (stamps that leave the fitted line and come back) is reported and accepted, dropped samples
  (whole periods) are counted; a gap (the stamps leave the line for good, or more than 10 samples lost in a
  row) is refused, naming the ``start_s`` / ``stop_s`` windows either side that import cleanly;
* dropouts and stuck samples (:mod:`calib.core.dropouts`): 50 or more identical rows of a triad in a row
  (all-zero rows of a logger stopping, a sensor's output stuck) are trimmed at the ends of the import (said
  in ``import_summary`` and the attribute ``dropouts_trimmed``) and refused inside, naming the windows.

Every failure raises :class:`ImportDataError` (a :class:`calib.io.recording.RecordingError`, hence a
``ValueError``) naming the file, the field and the fix.

Settings keys
-------------
Common to all formats:

``format`` (required)
    ``imu_tk`` | ``imucal`` | ``mikoff`` | ``npz_columns`` | ``columns`` | ``rosbag`` | ``matlab``; an example
    settings file of each is in ``config/import/examples``.
``latitude_deg`` (required), ``height_m`` (default 0), ``gravity_m_s2`` (optional local gravity, m s-2)
    Site; stored as global attributes. ``site_note``: free text on where the site values come from.
``sensor``, ``description``: free text stored as attributes.
``data_dir``: directory the file names are relative to; a relative ``data_dir`` is taken relative to the
    settings file's directory (:func:`load_settings`) or, for a dict built in code, the working directory.
    Without it (the shipped settings): the ``data_root`` given to :func:`load_settings` (a workflow config's
    ``data_root`` key), else ``$CALIB_DATA``, else the shared data folder ``../shared/data`` beside the
    repository (:func:`default_data_root`).
``accel``, ``gyro`` (required; ``columns``, ``npz_columns`` and ``matlab`` take one of them alone: a partial
    record of accelerometers only or gyroscopes only, the absent triad declared as such in the recording's
    ``absent_sensors`` attribute, never zero-filled): triad declarations, keys
    ``units`` (required; one of :data:`calib.io.recording.UNITS` for the kind), ``sample_kind`` (required:
    ``rate`` | ``increment``), ``columns`` (format dependent), ``scale`` (number or 3 numbers, default 1),
    ``sign`` (3 of +1/-1, default +1): stored value = sign * scale * raw, per body axis x, y, z (with
    ``columns`` this also remaps axes, e.g. to make a left-handed frame right-handed -- declared, never
    inferred); ``approx_counts_per_g`` (accel in counts: enables the gravity-norm check),
    ``approx_zero_count`` (accel counts at zero input, for that check only, default 0),
    ``approx_counts_per_deg_s`` (gyro in counts: enables the turn-angle check).
``units_check_tolerance``: relative tolerance of the gravity-norm check (default 0.2).
``start_s``, ``stop_s``: import only the samples with ``start_s <= t < stop_s``, seconds from the file's
    first sample (the windows a refusal names for a gap or a stuck run); stored as ``imported_rows``.
``dropout_min_rows``: fewest identical rows of a triad in a row taken for a dropout or a stuck sensor
    (default 50; raise it for a sensor filtered far below its output rate, 0 turns the check off).

Per format (see each function for details): ``imu_tk``: ``files: {accel, gyro}``, ``sample_rate_hz``
(optional nominal rate, checked against the timestamps). ``imucal``: ``file``, ``segments_file`` or
``label_column``, ``sample_column``, ``sample_rate_hz``, ``rotation: {angle_deg, sign, rate_deg_s}``,
``labels``. ``mikoff``: ``file``, ``sample_rate_hz``. ``npz_columns``: ``file``, ``sample_rate_hz``,
``data_key``, ``columns_key``. ``columns``: ``file``, ``delimiter``, ``header``, ``comment``,
``skip_rows``, ``time: {column, units}`` or ``sample_rate_hz``, ``temperature: {column}``. ``matlab``: ``file``,
per triad ``variable`` (+ ``columns``) or ``variables``, ``time: {variable, units}``, ``sample_rate_hz`` or
``sample_rate_variable``, ``temperature: {variable}`` (:mod:`calib.ingest.matlab`). ``rosbag``: ``file``,
``topic``, ``time_source``, ``temperature_topic``, ``sample_rate_hz`` (``start_s`` / ``stop_s`` in seconds
from the bag's first message of the topic).
"""
from calib.ingest.common import ImportDataError, default_data_root, load_settings
from calib.ingest.importers import FORMATS, IMPORTERS, import_dataset, import_recording

__all__ = ["FORMATS", "IMPORTERS", "ImportDataError", "default_data_root", "import_dataset", "import_recording",
           "load_settings"]
