"""Rule diagnosis_real_proof: detection limits and the injection proof on the shared real recordings, gathered from
the jobs of rule diagnosis_real_proof_recording."""
import os

from calib.core import progress as runlog
from calib.studies import real_proof

p = snakemake.params
c = p.cfg
with runlog.to_file(snakemake.log[0]):
    # a file per recording (Snakemake keeps a hidden time stamp beside them)
    parts = sorted(os.path.join(job, f) for job in snakemake.input.jobs for f in os.listdir(job) if f.endswith(".json"))
    real_proof.real_proof_gather(p.out, p.config_dir, parts,
                                 recordings=c.get("recordings") or None, reps=c.get("reps", 10),
                                 n_inject=c.get("n_inject", 100), n_out=c.get("n_out", 10), seed=p.seed,
                                 factor=c.get("factor", 2.0), metrics_path=snakemake.output.metrics,
                                 enforce=c.get("enforce", True))
