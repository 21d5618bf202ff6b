"""Rule simulate_navigation_session: He 2019 §IV.A stationary data, written in chunks."""
from calib.core import progress as runlog
from calib.studies import stages

with runlog.to_file(snakemake.log[0]):
    stages.simulate_navigation(snakemake.params.session, snakemake.params.site, snakemake.params.seed,
                               snakemake.output.recording, snakemake.output.truth, rule=snakemake.rule)
