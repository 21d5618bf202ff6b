"""Rule calibration_z: z-scores of the default calibration over independent noise seeds."""
from calib.studies import calibration as calibration_study
from calib.core import progress as runlog

p = snakemake.params
with runlog.to_file(snakemake.log[0]):
    o = snakemake.output
    calibration_study.run_z_seeds(p.session, p.site, p.calibration, p.calibration["z_seeds"], p.seed, o.table, o.fig,
                                  o.metrics, p.workdir, check=p.check,
                                  noise_record=snakemake.input.get("noise_record"), workers=snakemake.threads)
