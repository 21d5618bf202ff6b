# Diagnosis stage: does the base sensor model fit the recording, and if not, which physics is missing?
# `diagnose` runs on the study's recording (the synthetic calibration session, or the imported one of a
# real-recording study); `diagnosis_proof` is the concealed-effect proof (results/proof/); `diagnosis_real`
# diagnoses every shared real recording and one with a known term injected.


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


rule diagnosis_proof:
    """Concealed-effect sessions diagnosed blind over many noise seeds; detection power."""
    input:
        noise_record=f"{R}/data/static_check.nc",   # the unit's long static record: measured slow noise
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
        proof=lambda w: DIAG["proof"],
        settings=lambda w: DIAG.get("settings", {}),
        seed=config["seeds"]["diagnosis"],
        session=sub("calibration_session"),
        site=sub("site"),
        out=lambda w, output: os.path.dirname(output.proof),
    threads: 2
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


rule diagnosis_real_proof:
    """Real recordings as proof bases: detection limits per recording and effects injected at twice them."""
    input:
        settings=sorted(glob.glob("config/import/*.yaml")),
    output:
        proof=f"{R}/diagnosis/real_proof/real_proof.json",
        md=report(f"{R}/diagnosis/real_proof/real_proof.md", category="6 Diagnosis", caption="../report/real_proof.rst"),
        limits=report(f"{R}/diagnosis/real_proof/limits.csv", category="6 Diagnosis", caption="../report/real_proof.rst"),
        fig=report(f"{R}/diagnosis/real_proof/limits.png", category="6 Diagnosis", caption="../report/real_proof.rst"),
        metrics=f"{R}/diagnosis/real_proof/real_proof.metrics.json",
    params:
        cfg=lambda w: DIAG.get("real_proof", {}),
        settings=lambda w: DIAG.get("settings", {}),
        seed=config["seeds"]["diagnosis"],
        out=lambda w, output: os.path.dirname(output.proof),
        config_dir=lambda w, input: os.path.dirname(input.settings[0]),
    threads: 2
    log:
        f"{R}/logs/diagnosis_real_proof.log",
    benchmark:
        f"{R}/benchmarks/diagnosis_real_proof.tsv"
    conda:
        "../envs/calib.yaml"
    script:
        "../scripts/diagnosis_real_proof.py"
