# Gyro-drift estimation of He 2019: 50 PSOBE tests with the Cramér–Rao bound and the baselines, then 240 h validation;
# the estimators over many noise seeds against the bound (efficiency ratios).


rule drift_pso:
    input:
        recording=f"{R}/data/navigation_session.nc",
    output:
        tests=f"{R}/drift/pso_tests.nc",
        table=report(f"{R}/drift/table1_pso.csv", category="4 Gyro drift (He 2019)", caption="../report/table1_pso.rst"),
        baselines=report(f"{R}/drift/baselines.csv", category="4 Gyro drift (He 2019)", caption="../report/baselines.rst"),
        timings=f"{R}/drift/timings.csv",
        fig2=report(f"{R}/drift/figure2_estimates.png", category="4 Gyro drift (He 2019)", caption="../report/fig2_drift.rst"),
        fig3=report(f"{R}/drift/figure3_fitness.png", category="4 Gyro drift (He 2019)", caption="../report/fig3_drift.rst"),
        metrics=f"{R}/drift/pso.metrics.json",
    params:
        session=sub("navigation_session"),
        site=sub("site"),
        nav=sub("navigation"),
        drift=sub("drift"),
        seed=config["seeds"]["drift"],
    threads: 2
    log:
        f"{R}/logs/drift_pso.log",
    benchmark:
        f"{R}/benchmarks/drift_pso.tsv"
    conda:
        "../envs/calib.yaml"
    script:
        "../scripts/drift_pso.py"


rule drift_validation:
    input:
        recording=f"{R}/data/navigation_session.nc",
        tests=f"{R}/drift/pso_tests.nc",
    output:
        nav=f"{R}/drift/validation_240h.nc",
        fig4=report(f"{R}/drift/figure4_navigation.png", category="4 Gyro drift (He 2019)", caption="../report/fig4_drift.rst"),
        metrics=f"{R}/drift/validation.metrics.json",
    params:
        session=sub("navigation_session"),
        site=sub("site"),
        nav=sub("navigation"),
        drift=sub("drift"),
    threads: 2
    log:
        f"{R}/logs/drift_validation.log",
    benchmark:
        f"{R}/benchmarks/drift_validation.tsv"
    conda:
        "../envs/calib.yaml"
    script:
        "../scripts/drift_validation.py"


rule drift_noise_seeds:
    output:
        nc=f"{R}/drift/noise_seeds.nc",
        table=report(f"{R}/drift/noise_seeds.csv", category="4 Gyro drift (He 2019)", caption="../report/noise_seeds.rst"),
        fig=report(f"{R}/drift/noise_seeds_z.png", category="4 Gyro drift (He 2019)", caption="../report/noise_seeds.rst"),
        metrics=f"{R}/drift/noise_seeds.metrics.json",
    params:
        session=sub("navigation_session"),
        site=sub("site"),
        drift=sub("drift"),
        seed=session_seed(config["seeds"]["data"], "drift_noise_seeds"),
        workdir=lambda w, output: os.path.join(os.path.dirname(output.nc), "tmp_noise_seeds"),
    threads: 2
    log:
        f"{R}/logs/drift_noise_seeds.log",
    benchmark:
        f"{R}/benchmarks/drift_noise_seeds.tsv"
    conda:
        "../envs/calib.yaml"
    script:
        "../scripts/drift_noise_seeds.py"
