"""Rule calibration_z_seeds: one block of seeds of the z-score study (gathered by rule calibration_z)."""
from calib.core import progress as runlog
from calib.studies import calibration as calibration_study

p = snakemake.params
first, stop = int(snakemake.wildcards.first), int(snakemake.wildcards.stop)
with runlog.to_file(snakemake.log[0]):
    block = calibration_study.z_seed_block(p.session, p.site, p.calibration, p.seed, first, stop, p.workdir,
                                           check=p.check, noise_record=snakemake.input.get("noise_record"),
                                           workers=snakemake.threads)
    calibration_study.write_z_block(block, first, snakemake.output.part)
