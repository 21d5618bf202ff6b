"""Rule diagnosis_proof: the concealed-effect proof over noise seeds, with detection power."""
from calib.studies import diagnosis as diagnosis_study
from calib.core import progress as runlog
from calib.io.netcdf import provenance

p = snakemake.params
with runlog.to_file(snakemake.log[0]):
    pr = p.proof
    diagnosis_study.proof_stage(p.out, pr["n_seeds"], p.seed, p.settings, pr.get("sessions") or None,
                                pr["power_seeds"], workers=snakemake.threads, base=p.session, site=p.site,
                                prov=provenance(snakemake.rule, dict(p.items()), seed=p.seed),
                                metrics_path=snakemake.output.metrics)
