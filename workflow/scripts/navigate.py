"""Rule navigate: pure-inertial navigation of a recording (with a calibration for count data), errors to netCDF."""
import numba

from calib.studies import navigation_stage as navigation_study
from calib.core import progress as runlog
from calib.io.netcdf import provenance

numba.set_num_threads(snakemake.threads)
p = snakemake.params
with runlog.to_file(snakemake.log[0]):
    cal = snakemake.input.calibration or None
    navigation_study.navigate_file(snakemake.input.recording, cal if isinstance(cal, str) else (cal[0] if cal else None),
                                   snakemake.output.nc, p.nav, prov=provenance(snakemake.rule, dict(p.items())))
