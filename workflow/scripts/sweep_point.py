"""Rule sweep_point: one point of a parameter sweep (calib.studies.sweeps.run_point)."""
import numba

from calib.core import progress as runlog
from calib.studies import sweeps
from calib.io.netcdf import provenance

numba.set_num_threads(snakemake.threads)
p = snakemake.params
with runlog.to_file(snakemake.log[0]):
    sweeps.run_point(p.kind, snakemake.input.recording, snakemake.input.truth, p.cfg, p.values, snakemake.output.nc,
                     prov=provenance(snakemake.rule, p.cfg, p.cfg["seeds"]["data"]))
