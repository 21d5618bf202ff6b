"""Rule real_drift: PSOBE on a real static recording, checked against the mean gyro output."""
import numba

from calib.studies import drift as drift_study
from calib.core import progress as runlog

numba.set_num_threads(snakemake.threads)
with runlog.to_file(snakemake.log[0]):
    o = snakemake.output
    drift_study.run_real_drift(snakemake.input.recording, o.result, o.fig, o.metrics, snakemake.params.drift,
                               snakemake.params.seed)
