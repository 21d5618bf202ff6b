# Parameter sweeps (config/sweeps/*.yaml, listed under `sweeps:` in the study config; schema
# workflow/schemas/sweep.schema.yaml; library calib.studies.sweeps). Each sweep is a Paramspace over its grid: one
# synthetic session per combination of the data parameters (seed, noise level, ...), one job per point, and a
# gather job writing one labelled netCDF with the swept parameters as dimensions, a CSV and a summary figure.
# Not part of `all`: run `snakemake sweeps` (or ask for results/sweeps/<name>/sweep.nc).
import json
import os
import re

from calib.studies import sweep_spec as _sweeps

SWEEPS = _sweeps.load_all(
    config.get("sweeps", []),
    {k: v for k, v in config.items() if k not in ("sweeps", "scatter")},   # scatter: jobs, not results
    os.path.join(workflow.current_basedir, "..", "schemas", "sweep.schema.yaml"),
    os.path.join(workflow.current_basedir, "..", "..", "src", "calib", "resources", "config.schema.yaml"),
)
_SWEEP_NAMES = "|".join(re.escape(n) for n in SWEEPS) or "(?!)"


wildcard_constraints:
    sweep=_SWEEP_NAMES,


rule sweeps:
    input:
        [f"{R}/sweeps/{name}/sweep.nc" for name in SWEEPS],
        [f"{R}/sweeps/{name}/summary.png" for name in SWEEPS],
    default_target: False


rule sweep_session:
    output:
        recording=temp(f"{R}/sweeps/{{sweep}}/sessions/{{session}}.nc"),
        truth=temp(f"{R}/sweeps/{{sweep}}/sessions/{{session}}.truth.json"),
    params:
        cfg=lambda w: SWEEPS[w.sweep].session_config(w.session),
    wildcard_constraints:
        session="[^/]+",
    log:
        f"{R}/logs/sweeps/{{sweep}}/session_{{session}}.log",
    conda:
        "../envs/calib.yaml"
    script:
        "../scripts/sweep_session.py"


rule sweep_point:
    input:
        recording=lambda w: f"{R}/sweeps/{w.sweep}/sessions/{SWEEPS[w.sweep].session_of(w.point)}.nc",
        truth=lambda w: f"{R}/sweeps/{w.sweep}/sessions/{SWEEPS[w.sweep].session_of(w.point)}.truth.json",
    output:
        nc=f"{R}/sweeps/{{sweep}}/points/{{point}}.nc",
    params:
        kind=lambda w: SWEEPS[w.sweep].kind,
        values=lambda w: SWEEPS[w.sweep].values(w.point),
        cfg=lambda w: SWEEPS[w.sweep].point_config(w.point),
    wildcard_constraints:
        point="[^/]+",
    threads: 1
    log:
        f"{R}/logs/sweeps/{{sweep}}/{{point}}.log",
    benchmark:
        f"{R}/sweeps/{{sweep}}/benchmarks/{{point}}.tsv"
    conda:
        "../envs/calib.yaml"
    script:
        "../scripts/sweep_point.py"


rule sweep_gather:
    input:
        points=lambda w: [f"{R}/sweeps/{w.sweep}/points/{p}.nc" for p in SWEEPS[w.sweep].points],
    output:
        nc=f"{R}/sweeps/{{sweep}}/sweep.nc",
        table=report(f"{R}/sweeps/{{sweep}}/summary.csv", category="6 Sweeps", subcategory="{sweep}", caption="../report/sweep_table.rst"),
        fig=report(f"{R}/sweeps/{{sweep}}/summary.png", category="6 Sweeps", subcategory="{sweep}", caption="../report/sweep.rst"),
        metrics=f"{R}/sweeps/{{sweep}}/sweep.metrics.json",
    params:
        kind=lambda w: SWEEPS[w.sweep].kind,
        columns=lambda w: SWEEPS[w.sweep].columns,
        values=lambda w: [SWEEPS[w.sweep].values(p) for p in SWEEPS[w.sweep].points],
        attrs=lambda w: {"sweep_file": SWEEPS[w.sweep].path, "description": SWEEPS[w.sweep].description,
                         "fixed": json.dumps(SWEEPS[w.sweep].fixed, sort_keys=True),
                         "base": json.dumps(SWEEPS[w.sweep].base, sort_keys=True)},
    log:
        f"{R}/logs/sweeps/{{sweep}}/gather.log",
    conda:
        "../envs/calib.yaml"
    script:
        "../scripts/sweep_gather.py"
