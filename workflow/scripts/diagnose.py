"""Rule diagnose: mismatch diagnosis of the study's recording (report.json, report.md, figures)."""
from calib.studies import diagnosis_stage as diagnosis_study
from calib.core import progress as runlog

p = snakemake.params
with runlog.to_file(snakemake.log[0]):
    settings = dict(p.settings)
    if snakemake.input.get("noise_record"):
        settings["noise_record"] = snakemake.input.noise_record
    diagnosis_study.diagnose_session(snakemake.input.recording, p.out, settings, snakemake.output.metrics,
                                     fieldcal_path=snakemake.input.get("fieldcal"))
