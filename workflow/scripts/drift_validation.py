"""Rule drift_validation: 240 h navigation with and without compensation (He 2019 Figure 4)."""
import numba

from calib.studies import drift as drift_study
from calib.core import progress as runlog
from calib.io.netcdf import provenance

numba.set_num_threads(snakemake.threads)
p = snakemake.params
with runlog.to_file(snakemake.log[0]):
    o = snakemake.output
    drift_study.run_validation(snakemake.input.recording, snakemake.input.tests, o.nav, o.fig4, o.metrics,
                               p.session, p.site, p.nav, p.drift, prov=provenance(snakemake.rule, dict(p.items())))
