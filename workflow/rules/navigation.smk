# Navigation stage: Liu 2021's static-navigation check (Figure 10) with each method's calibration.


rule static_check:
    input:
        recording=f"{R}/data/static_check.nc",
        default=f"{R}/calibration/default_calibration.nc",
        runs=f"{R}/calibration/runs",
    output:
        nc=f"{R}/navigation/static_check.nc",
        fig=report(f"{R}/navigation/figure10_static_check.png", category="3 Navigation", caption="../report/fig10.rst"),
        metrics=f"{R}/navigation/static_check.metrics.json",
    params:
        check=sub("static_check"),
        nav=sub("navigation"),
        cal_dir=lambda w, input: os.path.dirname(input.default),
    threads: 2
    log:
        f"{R}/logs/static_check.log",
    benchmark:
        f"{R}/benchmarks/static_check.tsv"
    conda:
        "../envs/calib.yaml"
    script:
        "../scripts/static_check.py"


rule navigate:
    """Any recording of the data stage with the default calibration (count recordings) -> navigation errors."""
    input:
        recording=f"{R}/data/{{session}}.nc",
        calibration=lambda w: [] if w.session == "navigation_session" else f"{R}/calibration/default_calibration.nc",
    output:
        nc=f"{R}/navigation/{{session}}_errors.nc",
    params:
        nav=sub("navigation"),
    wildcard_constraints:
        session="calibration_session|static_check|navigation_session",
    threads: 2
    log:
        f"{R}/logs/navigate_{{session}}.log",
    benchmark:
        f"{R}/benchmarks/navigate_{{session}}.tsv"
    conda:
        "../envs/calib.yaml"
    script:
        "../scripts/navigate.py"
