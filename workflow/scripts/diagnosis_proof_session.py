"""Rule diagnosis_proof_session: one session of the concealed-effect proof over its noise seeds, with its
detection-power scan."""
from calib.core import progress as runlog
from calib.studies import diagnosis_stage as diagnosis_study

p = snakemake.params
with runlog.to_file(snakemake.log[0]):
    pr = p.proof
    settings = {**p.settings, "noise_record": snakemake.input.noise_record}  # the unit's measured slow noise
    diagnosis_study.proof_session_stage(snakemake.wildcards.proof_session, snakemake.output.part, pr["n_seeds"],
                                        p.seed, settings, base=p.session, site=p.site,
                                        power_seeds=pr["power_seeds"], injection=pr.get("injection", "physical"),
                                        noise_store=snakemake.input.noise_store)
