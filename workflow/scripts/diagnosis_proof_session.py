"""Rule diagnosis_proof_session: sessions of the concealed-effect proof over their noise seeds, each with its
detection-power scan, into a folder per session."""
import os

from calib.core import progress as runlog
from calib.studies import diagnosis_stage as diagnosis_study

p = snakemake.params
with runlog.to_file(snakemake.log[0]):
    pr = p.proof
    settings = {**p.settings, "noise_record": snakemake.input.noise_record}  # the unit's measured slow noise
    for name in p.sessions:
        diagnosis_study.proof_session_stage(name, os.path.join(snakemake.output.part, name), pr["n_seeds"],
                                            p.seed, settings, base=p.session, site=p.site,
                                            power_seeds=pr["power_seeds"], injection=pr.get("injection", "physical"),
                                            noise_store=snakemake.input.noise_store)
