"""Rule sweep_session: the synthetic session shared by the points of a sweep with the same data parameters."""
from calib.core import progress as runlog
from calib.studies import sweeps

with runlog.to_file(snakemake.log[0]):
    sweeps.simulate_session(snakemake.params.cfg, snakemake.output.recording, snakemake.output.truth,
                            rule=snakemake.rule)
