"""Rule diagnose: mismatch diagnosis of the study's recording (report.json, report.md, figures)."""
from calib import diagnosis_study, runlog

p = snakemake.params
with runlog.to_file(snakemake.log[0]):
    diagnosis_study.diagnose_session(snakemake.input.recording, p.out, p.settings, snakemake.output.metrics,
                                     fieldcal_path=snakemake.input.get("fieldcal"))
