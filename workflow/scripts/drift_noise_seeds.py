"""Rule drift_noise_seeds: the drift estimators over many noise seeds against the Cramér–Rao bound, gathered from
the seed blocks of rule drift_noise_seeds_block."""
from calib.core import progress as runlog
from calib.io.netcdf import provenance
from calib.studies import drift as drift_study

p = snakemake.params
with runlog.to_file(snakemake.log[0]):
    o = snakemake.output
    drift_study.noise_seed_products(drift_study.read_noise_seed_blocks(snakemake.input.parts), o.nc, o.table, o.fig,
                                    o.metrics, p.session, p.drift, p.drift["noise_seeds"], p.seed,
                                    prov=provenance(snakemake.rule, dict(p.items()), p.seed), workdir=p.workdir)
