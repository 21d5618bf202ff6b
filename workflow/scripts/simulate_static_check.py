"""Rule simulate_static_check: a static recording of the same simulated unit (Liu 2021 §4, Figure 10)."""
from calib.core import progress as runlog
from calib.studies import stages

with runlog.to_file(snakemake.log[0]):
    stages.simulate_static_check(snakemake.params.check, snakemake.params.session, snakemake.params.site,
                                 snakemake.params.seed, snakemake.output.recording, snakemake.output.truth,
                                 rule=snakemake.rule)
