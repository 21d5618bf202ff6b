"""Rule diagnosis_real_proof_recording: detection limits and the injection proof on shared real recordings, a part
file per recording."""
import os

from calib.core import progress as runlog
from calib.studies import real_proof

p = snakemake.params
c = p.cfg
with runlog.to_file(snakemake.log[0]):
    for settings_path in snakemake.input.settings:
        r = real_proof.real_proof_recording(settings_path, p.settings, reps=c.get("reps", 10),
                                            n_inject=c.get("n_inject", 100), n_out=c.get("n_out", 10), seed=p.seed,
                                            factor=c.get("factor", 2.0), axes=tuple(c.get("axes") or ("x", "y", "z")))
        name = os.path.splitext(os.path.basename(settings_path))[0]
        real_proof.write_part(r, os.path.join(snakemake.output.part, f"{name}.json"))
        print(f"{r['recording']}: usable {r.get('usable')}" + (f" ({r['why']})" if r.get("why") else ""))
