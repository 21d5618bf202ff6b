# Diagnosis stage: does the base sensor model fit the recording, and if not, which physics is missing?
# `diagnose` runs on the study's recording (the synthetic calibration session, or the imported one of a
# real-recording study); the concealed-effect proof (results/proof/) runs its sessions, each with its detection-power
# scan, in the jobs of `diagnosis_proof_session` (a job per session, or per share of them: `scatter` in common.smk),
# gathered by `diagnosis_proof`; the real-recording proof its recordings in the jobs of
# `diagnosis_real_proof_recording`, gathered by `diagnosis_real_proof`; `diagnosis_real` diagnoses every shared real
# recording and one with a known term injected. The jobs' parts are temporary: the gathered products are those of
# one job running them all.
from calib.studies import proof_sessions as _proof_sessions  # plain data: no numerical import when parsing

PROOF_NAMES = _proof_sessions.session_names(DIAG.get("proof", {}).get("sessions"))
# the real recordings of the proof (config/import/*.yaml, or the configured subset; an unknown name is refused by
# the gathering job, which names the known ones)
_REAL_PROOF_ALL = sorted(os.path.splitext(os.path.basename(p))[0] for p in glob.glob("config/import/*.yaml"))
REAL_PROOF_NAMES = [n for n in _REAL_PROOF_ALL
                    if not DIAG.get("real_proof", {}).get("recordings") or n in DIAG["real_proof"]["recordings"]]
# their jobs (`scatter` in common.smk): {job name: the sessions / recordings it runs, in turn}
PROOF_JOBS = scatter(PROOF_NAMES)
REAL_PROOF_JOBS = scatter(REAL_PROOF_NAMES)


wildcard_constraints:
    proof_job="[A-Za-z0-9_]+",
    real_proof_job="[A-Za-z0-9_.-]+",


rule diagnose:
    input:
        unpack(diagnosis_input),
    output:
        report=f"{R}/diagnosis/report.json",
        md=f"{R}/diagnosis/report.md",
        metrics=f"{R}/diagnosis/diagnosis.metrics.json",
    params:
        settings=lambda w: DIAG.get("settings", {}),
        out=lambda w, output: os.path.dirname(output.report),
    log:
        f"{R}/logs/diagnose.log",
    benchmark:
        f"{R}/benchmarks/diagnose.tsv"
    conda:
        "../envs/calib.yaml"
    script:
        "../scripts/diagnose.py"


rule diagnosis_proof_noise_store:
    """An empty folder the sessions' jobs share their seeds' noise in (removed when they are done): a seed drawn by
    one job is read by the others instead of drawn again, as in one process."""
    output:
        temp(directory(f"{R}/proof/parts/noise")),
    localrule: True
    log:
        f"{R}/logs/diagnosis_proof/noise_store.log",
    conda:
        "../envs/calib.yaml"
    shell:
        "mkdir -p {output} 2> {log}"


rule diagnosis_proof_session:
    """Concealed-effect sessions diagnosed blind over their noise seeds, each with its detection-power scan when it
    hides a single effect (a job per session, or per share of the sessions: PROOF_JOBS); a folder per session."""
    input:
        noise_record=f"{R}/data/static_check.nc",   # the unit's long static record: measured slow noise
        noise_store=f"{R}/proof/parts/noise",
    output:
        part=temp(directory(f"{R}/proof/parts/sessions/{{proof_job}}")),
    params:
        sessions=lambda w: PROOF_JOBS[w.proof_job],
        proof=lambda w: DIAG["proof"],
        settings=lambda w: DIAG.get("settings", {}),
        seed=config["seeds"]["diagnosis"],
        session=sub("calibration_session"),
        site=sub("site"),
    threads: 1
    log:
        f"{R}/logs/diagnosis_proof/{{proof_job}}.log",
    benchmark:
        f"{R}/benchmarks/diagnosis_proof_session.{{proof_job}}.tsv"
    conda:
        "../envs/calib.yaml"
    script:
        "../scripts/diagnosis_proof_session.py"


rule diagnosis_proof:
    """Concealed-effect sessions diagnosed blind over many noise seeds; detection power (gathered from the
    sessions' jobs)."""
    input:
        jobs=expand(f"{R}/proof/parts/sessions/{{proof_job}}", proof_job=PROOF_JOBS),
    output:
        proof=f"{R}/proof/proof.json",
        table=report(f"{R}/proof/proof.csv", category="6 Diagnosis", caption="../report/proof.rst"),
        md=f"{R}/proof/proof.md",
        nc=f"{R}/proof/proof.nc",
        power=report(f"{R}/proof/power.csv", category="6 Diagnosis", caption="../report/power.rst"),
        power_fig=report(f"{R}/proof/power.png", category="6 Diagnosis", caption="../report/power.rst"),
        figs=report(directory(f"{R}/proof/figures"), patterns=["{name}.png"], category="6 Diagnosis", caption="../report/proof_residuals.rst"),
        e2e=directory(f"{R}/proof/end_to_end"),
        timings=f"{R}/proof/timings.json",
        metrics=f"{R}/proof/proof.metrics.json",
    params:
        # the same params as the proof's sessions (and out): the netCDF's provenance (config_hash) hashes them
        proof=lambda w: DIAG["proof"],
        settings=lambda w: DIAG.get("settings", {}),
        seed=config["seeds"]["diagnosis"],
        session=sub("calibration_session"),
        site=sub("site"),
        out=lambda w, output: os.path.dirname(output.proof),
    threads: 1
    log:
        f"{R}/logs/diagnosis_proof.log",
    benchmark:
        f"{R}/benchmarks/diagnosis_proof.tsv"
    conda:
        "../envs/calib.yaml"
    script:
        "../scripts/diagnosis_proof.py"


rule diagnosis_real:
    """Every shared real recording (config/import/*.yaml), and the IMU-TK session with a known term added."""
    input:
        settings=sorted(glob.glob("config/import/*.yaml")),
    output:
        real=f"{R}/diagnosis/real/real.json",
        metrics=f"{R}/diagnosis/real/real.metrics.json",
    params:
        settings=lambda w: DIAG.get("settings", {}),
        inject=lambda w: DIAG.get("inject", {}),
        out=lambda w, output: os.path.dirname(output.real),
        config_dir=lambda w, input: os.path.dirname(input.settings[0]),
    log:
        f"{R}/logs/diagnosis_real.log",
    benchmark:
        f"{R}/benchmarks/diagnosis_real.tsv"
    conda:
        "../envs/calib.yaml"
    script:
        "../scripts/diagnosis_real.py"


rule diagnosis_real_proof_recording:
    """Real recordings as proof bases, each with its detection limits and the effects injected at twice them (a job
    per recording, or per share of them: REAL_PROOF_JOBS); a part file per recording."""
    input:
        settings=lambda w: [f"config/import/{n}.yaml" for n in REAL_PROOF_JOBS[w.real_proof_job]],
    output:
        part=temp(directory(f"{R}/diagnosis/real_proof/parts/{{real_proof_job}}")),
    params:
        cfg=lambda w: DIAG.get("real_proof", {}),
        settings=lambda w: DIAG.get("settings", {}),
        seed=config["seeds"]["diagnosis"],
    threads: 1
    log:
        f"{R}/logs/diagnosis_real_proof/{{real_proof_job}}.log",
    benchmark:
        f"{R}/benchmarks/diagnosis_real_proof_recording.{{real_proof_job}}.tsv"
    conda:
        "../envs/calib.yaml"
    script:
        "../scripts/diagnosis_real_proof_recording.py"


rule diagnosis_real_proof:
    """Real recordings as proof bases: detection limits per recording and effects injected at twice them (gathered
    from the recordings' jobs)."""
    input:
        settings=sorted(glob.glob("config/import/*.yaml")),
        jobs=expand(f"{R}/diagnosis/real_proof/parts/{{real_proof_job}}", real_proof_job=REAL_PROOF_JOBS),
    output:
        proof=f"{R}/diagnosis/real_proof/real_proof.json",
        md=report(f"{R}/diagnosis/real_proof/real_proof.md", category="6 Diagnosis", caption="../report/real_proof.rst"),
        limits=report(f"{R}/diagnosis/real_proof/limits.csv", category="6 Diagnosis", caption="../report/real_proof.rst"),
        fig=report(f"{R}/diagnosis/real_proof/limits.png", category="6 Diagnosis", caption="../report/real_proof.rst"),
        metrics=f"{R}/diagnosis/real_proof/real_proof.metrics.json",
    params:
        cfg=lambda w: DIAG.get("real_proof", {}),
        seed=config["seeds"]["diagnosis"],
        out=lambda w, output: os.path.dirname(output.proof),
        config_dir=lambda w, input: os.path.dirname(input.settings[0]),
    threads: 1
    log:
        f"{R}/logs/diagnosis_real_proof.log",
    benchmark:
        f"{R}/benchmarks/diagnosis_real_proof.tsv"
    conda:
        "../envs/calib.yaml"
    script:
        "../scripts/diagnosis_real_proof.py"
