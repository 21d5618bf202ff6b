"""Rule drift_pso: He 2019 Table 1, Figures 2-3, the Cramér–Rao bound and the baselines."""
import numba

from calib.studies import drift as drift_study
from calib.core import progress as runlog
from calib.io.netcdf import provenance

numba.set_num_threads(snakemake.threads)
p = snakemake.params
with runlog.to_file(snakemake.log[0]):
    o = snakemake.output
    drift_study.run_pso_tests(snakemake.input.recording, o.tests, o.table, o.baselines, o.timings, o.fig2, o.fig3,
                              o.metrics, p.session, p.site, p.nav, p.drift, p.seed,
                              prov=provenance(snakemake.rule, dict(p.items()), p.seed))
