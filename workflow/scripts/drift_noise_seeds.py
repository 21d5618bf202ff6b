"""Rule drift_noise_seeds: the drift estimators over many noise seeds against the Cramér–Rao bound."""
import numba

from calib.studies import drift as drift_study
from calib.core import progress as runlog
from calib.io.netcdf import provenance

numba.set_num_threads(snakemake.threads)
p = snakemake.params
with runlog.to_file(snakemake.log[0]):
    o = snakemake.output
    drift_study.run_noise_seeds(o.nc, o.table, o.fig, o.metrics, p.session, p.site, p.drift, p.drift["noise_seeds"],
                                p.seed, p.workdir, prov=provenance(snakemake.rule, dict(p.items()), p.seed))
