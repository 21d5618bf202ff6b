"""Rule diagnose: mismatch diagnosis of the study's recording (report.json, report.md, figures)."""
from calib.studies import diagnosis as diagnosis_study
from calib.core import progress as runlog

p = snakemake.params
with runlog.to_file(snakemake.log[0]):
    diagnosis_study.diagnose_session(snakemake.input.recording, p.out, p.settings, snakemake.output.metrics,
                                     fieldcal_path=snakemake.input.get("fieldcal"))
