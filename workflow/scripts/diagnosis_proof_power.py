"""Rule diagnosis_proof_power: the detection-power scan of one single-effect session of the proof."""
from calib.core import progress as runlog
from calib.studies import diagnosis as diagnosis_study

p = snakemake.params
with runlog.to_file(snakemake.log[0]):
    pr = p.proof
    settings = {**p.settings, "noise_record": snakemake.input.noise_record}  # the unit's measured slow noise
    diagnosis_study.power_scan_stage(snakemake.input.session, snakemake.output.part, pr["power_seeds"], p.seed,
                                     settings, base=p.session, site=p.site, injection=pr.get("injection", "physical"))
