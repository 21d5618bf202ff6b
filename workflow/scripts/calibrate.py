"""Rule calibrate: the Liu 2021 calibration study on the session."""
from calib.studies import calibration as calibration_study
from calib.core import progress as runlog
from calib.io.netcdf import provenance

p = snakemake.params
with runlog.to_file(snakemake.log[0]):
    calibration_study.run_study(snakemake.input.recording, snakemake.input.truth, p.out, p.calibration, p.seed,
                                prov=provenance(snakemake.rule, dict(p.items()), p.seed), workers=snakemake.threads,
                                noise_record=snakemake.input.get("noise_record"))
