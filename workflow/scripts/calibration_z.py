"""Rule calibration_z: z-scores of the default calibration over independent noise seeds, gathered from the seed
blocks of rule calibration_z_seeds."""
from calib.studies import calibration as calibration_study
from calib.core import progress as runlog

p = snakemake.params
with runlog.to_file(snakemake.log[0]):
    o = snakemake.output
    calibration_study.z_products(calibration_study.read_z_blocks(snakemake.input.parts), p.calibration,
                                 p.calibration["z_seeds"], o.table, o.fig, o.metrics)
