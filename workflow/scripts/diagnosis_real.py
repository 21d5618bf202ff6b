"""Rule diagnosis_real: diagnose every shared real recording, and one with a known term injected."""
from calib.studies import diagnosis_stage as diagnosis_study
from calib.core import progress as runlog

p = snakemake.params
with runlog.to_file(snakemake.log[0]):
    diagnosis_study.real_stage(p.out, p.settings, p.config_dir, p.inject or None, snakemake.output.metrics)
