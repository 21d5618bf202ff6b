"""Rule fieldcal: calibration without a turntable record (gravity norm + gyro-integrated gravity direction)."""
from calib.studies import realdata
from calib.core import progress as runlog
from calib.io.netcdf import provenance

with runlog.to_file(snakemake.log[0]):
    o = snakemake.output
    realdata.calibrate(snakemake.input.recording, snakemake.params.settings, o.result, o.summary, o.fig, o.metrics,
                       prov=provenance(snakemake.rule, snakemake.params.settings))
