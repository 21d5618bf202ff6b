# Calibration stage (Liu 2021): noise, repeated identifications per method, Tables 2, 4, 5, Figures 2-6 and 8,
# identifiability, and the default calibration used by the navigation stage.


rule calibrate:
    input:
        unpack(noise_record_input),
        recording=f"{R}/data/calibration_session.nc",
        truth=f"{R}/truth/calibration_session.truth.json",
    output:
        table2=report(f"{R}/calibration/tables/table2_de_variants.csv", category="2 Calibration (Liu 2021)", caption="../report/table2.rst"),
        table4=report(f"{R}/calibration/tables/table4_gyro_paths.csv", category="2 Calibration (Liu 2021)", caption="../report/table4.rst"),
        table5=report(f"{R}/calibration/tables/table5_methods.csv", category="2 Calibration (Liu 2021)", caption="../report/table5.rst"),
        ident=f"{R}/calibration/identifiability.json",
        default=f"{R}/calibration/default_calibration.nc",
        default_json=f"{R}/calibration/default_calibration.json",
        noise=f"{R}/calibration/noise.nc",
        figs=report(directory(f"{R}/calibration/figures"), patterns=["{name}.png"], category="2 Calibration (Liu 2021)", caption="../report/calibration_figures.rst"),
        runs=directory(f"{R}/calibration/runs"),
        timings=f"{R}/calibration/timings.csv",
        metrics=f"{R}/calibration/calibration.metrics.json",
    params:
        calibration=sub("calibration"),
        seed=config["seeds"]["calibration"],
        out=lambda w, output: os.path.dirname(output.ident),
    threads: 2
    log:
        f"{R}/logs/calibrate.log",
    benchmark:
        f"{R}/benchmarks/calibrate.tsv"
    conda:
        "../envs/calib.yaml"
    script:
        "../scripts/calibrate.py"


rule calibration_z:
    """The default calibration over independent noise seeds: z-scores of every identified parameter."""
    input:
        unpack(z_noise_record_input),
    output:
        table=report(f"{R}/calibration/zscores.csv", category="2 Calibration (Liu 2021)", caption="../report/zscores.rst"),
        fig=report(f"{R}/calibration/zscores.png", category="2 Calibration (Liu 2021)", caption="../report/zscores.rst"),
        metrics=f"{R}/calibration/zscores.metrics.json",
    params:
        session=sub("calibration_session"),
        site=sub("site"),
        calibration=sub("calibration"),
        check=sub("static_check"),
        seed=session_seed(config["seeds"]["data"], "calibration_z"),
        workdir=lambda w, output: os.path.join(os.path.dirname(output.table), "tmp_zscores"),
    threads: 2  # seeds in forked workers; the result does not depend on their number
    log:
        f"{R}/logs/calibration_z.log",
    benchmark:
        f"{R}/benchmarks/calibration_z.tsv"
    conda:
        "../envs/calib.yaml"
    script:
        "../scripts/calibration_z.py"
