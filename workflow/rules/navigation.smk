# Navigation stage: seed 000's static-navigation check (Figure 10) with each method's calibration.


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
