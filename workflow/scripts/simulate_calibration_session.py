"""Rule simulate_calibration_session: the Liu 2021 calibration path as a calib-recording-1 file."""
from calib.core import progress as runlog
from calib.studies import stages

with runlog.to_file(snakemake.log[0]):
    stages.simulate_calibration(snakemake.params.session, snakemake.params.site, snakemake.params.seed,
                                snakemake.output.recording, snakemake.output.truth, rule=snakemake.rule)
