# Data stage: synthetic sessions (Liu 2021 calibration path, static check, He 2019 stationary data).


rule simulate_calibration_session:
    output:
        recording=f"{R}/data/calibration_session.nc",
        truth=f"{R}/truth/calibration_session.truth.json",
    params:
        session=sub("calibration_session"),
        site=sub("site"),
        seed=session_seed(config["seeds"]["data"], "calibration_session"),
    log:
        f"{R}/logs/simulate_calibration_session.log",
    benchmark:
        f"{R}/benchmarks/simulate_calibration_session.tsv"
    conda:
        "../envs/calib.yaml"
    script:
        "../scripts/simulate_calibration_session.py"


rule simulate_static_check:
    output:
        recording=f"{R}/data/static_check.nc",
        truth=f"{R}/truth/static_check.truth.json",
    params:
        check=sub("static_check"),
        session=sub("calibration_session"),
        site=sub("site"),
        seed=session_seed(config["seeds"]["data"], "static_check"),
    log:
        f"{R}/logs/simulate_static_check.log",
    benchmark:
        f"{R}/benchmarks/simulate_static_check.tsv"
    conda:
        "../envs/calib.yaml"
    script:
        "../scripts/simulate_static_check.py"


rule simulate_navigation_session:
    output:
        recording=f"{R}/data/navigation_session.nc",
        truth=f"{R}/truth/navigation_session.truth.json",
    params:
        session=sub("navigation_session"),
        site=sub("site"),
        seed=session_seed(config["seeds"]["data"], "navigation_session"),
    log:
        f"{R}/logs/simulate_navigation_session.log",
    benchmark:
        f"{R}/benchmarks/simulate_navigation_session.tsv"
    conda:
        "../envs/calib.yaml"
    script:
        "../scripts/simulate_navigation_session.py"
