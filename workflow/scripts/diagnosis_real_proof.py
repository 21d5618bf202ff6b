"""Rule diagnosis_real_proof: detection limits and the injection proof on the shared real recordings."""
from calib.core import progress as runlog
from calib.studies import real_proof

p = snakemake.params
c = p.cfg
with runlog.to_file(snakemake.log[0]):
    real_proof.real_proof_stage(p.out, p.config_dir, p.settings, reps=c.get("reps", 10),
                                n_inject=c.get("n_inject", 100), n_out=c.get("n_out", 10), seed=p.seed,
                                factor=c.get("factor", 2.0), recordings=c.get("recordings") or None,
                                axes=tuple(c.get("axes") or ("x", "y", "z")),
                                workers=snakemake.threads, metrics_path=snakemake.output.metrics,
                                enforce=c.get("enforce", True))
