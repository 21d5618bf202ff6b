"""Rule diagnosis_proof: the concealed-effect proof over noise seeds, with detection power."""
from calib.studies import diagnosis as diagnosis_study
from calib.core import progress as runlog
from calib.io.netcdf import provenance

p = snakemake.params
with runlog.to_file(snakemake.log[0]):
    pr = p.proof
    settings = {**p.settings, "noise_record": snakemake.input.noise_record}  # the unit's measured slow noise
    diagnosis_study.proof_stage(p.out, pr["n_seeds"], p.seed, settings, pr.get("sessions") or None,
                                pr["power_seeds"], workers=snakemake.threads, base=p.session, site=p.site,
                                prov=provenance(snakemake.rule, dict(p.items()), seed=p.seed),
                                metrics_path=snakemake.output.metrics, enforce=pr.get("enforce", True),
                                injection=pr.get("injection", "physical"))
