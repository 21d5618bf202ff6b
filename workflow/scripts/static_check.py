"""Rule static_check: Liu 2021 Figure 10, static navigation with each method's calibration."""
import numba

from calib.studies import navigation_stage as navigation_study
from calib.core import progress as runlog
from calib.io.netcdf import provenance

numba.set_num_threads(snakemake.threads)
p = snakemake.params
with runlog.to_file(snakemake.log[0]):
    o = snakemake.output
    navigation_study.run_static_check(snakemake.input.recording, p.cal_dir, o.nc, o.fig, o.metrics, p.check, p.nav,
                                      prov=provenance(snakemake.rule, dict(p.items())))
