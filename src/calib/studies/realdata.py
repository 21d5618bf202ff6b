"""Real-recording stage: field calibration of an imported recording, with its static-detection figure."""
from __future__ import annotations

import json

import numpy as np

from calib import fieldcal
from calib.figures import segment_plots
from calib.io import recording
from calib.io.netcdf import write_netcdf
from calib.io.atomic import write_text


def calibrate(recording_path, settings: dict, out_nc, out_json, fig, metrics_path, prov=None, log=print):
    """Calibrate without a turntable record; write the result (netCDF), its summary (JSON), the detected
    static intervals over the signal (figure) and the key metrics."""
    ds = recording.load(recording_path)
    res = fieldcal.fieldcal_recording(ds, settings)
    write_netcdf(res.to_dataset(), out_nc, prov)
    summary = res.summary()
    write_text(out_json, json.dumps(summary, indent=2, default=str))
    segment_plots.static_intervals(ds, np.asarray(res.intervals, dtype=np.int64).reshape(-1, 2), res.detection_rule,
                                   fig)
    metrics = {k: v for k, v in summary.items() if isinstance(v, (int, float))}
    metrics.update({k: v for k, v in getattr(res, "metrics", {}).items() if isinstance(v, (int, float))})
    write_text(metrics_path, json.dumps(metrics, indent=2))
    log(json.dumps(summary, indent=2, default=str))
    return res
