"""Rule diagnosis_proof: the concealed-effect proof over noise seeds, with detection power, gathered from the jobs
of rule diagnosis_proof_session."""
import os

from calib.studies import diagnosis_stage as diagnosis_study
from calib.core import progress as runlog
from calib.io.netcdf import provenance

p = snakemake.params
with runlog.to_file(snakemake.log[0]):
    pr = p.proof
    # a folder per session (Snakemake keeps a hidden time stamp beside them)
    parts = sorted(os.path.join(job, s) for job in snakemake.input.jobs for s in os.listdir(job) if s[0] != ".")
    diagnosis_study.proof_gather_stage(p.out, parts, pr["n_seeds"], p.seed,
                                       pr.get("sessions") or None, pr["power_seeds"],
                                       prov=provenance(snakemake.rule, dict(p.items()), seed=p.seed),
                                       metrics_path=snakemake.output.metrics, enforce=pr.get("enforce", True),
                                       injection=pr.get("injection", "physical"))
