"""Rule drift_noise_seeds_block: one block of seeds of the noise-seed study (gathered by rule drift_noise_seeds)."""
import numba

from calib.core import progress as runlog
from calib.studies import drift as drift_study

numba.set_num_threads(snakemake.threads)
p = snakemake.params
first, stop = int(snakemake.wildcards.first), int(snakemake.wildcards.stop)
with runlog.to_file(snakemake.log[0]):
    block = drift_study.noise_seed_block(p.session, p.site, p.drift, p.seed, first, stop, p.workdir)
    drift_study.write_noise_seed_block(block, snakemake.output.part)
