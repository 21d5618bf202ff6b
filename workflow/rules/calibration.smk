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


# The z-score study's seeds in blocks of at most Z_SEEDS_PER_JOB, one job each (seed_blocks in common.smk).
Z_SEEDS_PER_JOB = 100
Z_BLOCKS = seed_blocks(int(CAL.get("z_seeds", 0)), Z_SEEDS_PER_JOB)


rule calibration_z_seeds:
    """A block of seeds of the z-score study (seeds first .. stop - 1)."""
    input:
        unpack(z_noise_record_input),
    output:
        part=temp(f"{R}/calibration/zscores_parts/{{first}}_{{stop}}.json"),
    params:
        session=sub("calibration_session"),
        site=sub("site"),
        calibration=sub("calibration"),
        check=sub("static_check"),
        seed=session_seed(config["seeds"]["data"], "calibration_z"),
        # the study's scratch folder (used by the file path only; removed when empty), shared by the blocks
        workdir=lambda w, output: os.path.join(os.path.dirname(os.path.dirname(output.part)), "tmp_zscores"),
    wildcard_constraints:
        first="[0-9]+",
        stop="[0-9]+",
    threads: 1
    log:
        f"{R}/logs/calibration_z/{{first}}_{{stop}}.log",
    benchmark:
        f"{R}/benchmarks/calibration_z_seeds.{{first}}_{{stop}}.tsv"
    conda:
        "../envs/calib.yaml"
    script:
        "../scripts/calibration_z_seeds.py"


rule calibration_z:
    """The default calibration over independent noise seeds: z-scores of every identified parameter (gathered from
    the seed blocks' jobs)."""
    input:
        parts=expand(f"{R}/calibration/zscores_parts/{{block}}.json", block=Z_BLOCKS),
    output:
        table=report(f"{R}/calibration/zscores.csv", category="2 Calibration (Liu 2021)", caption="../report/zscores.rst"),
        fig=report(f"{R}/calibration/zscores.png", category="2 Calibration (Liu 2021)", caption="../report/zscores.rst"),
        metrics=f"{R}/calibration/zscores.metrics.json",
    params:
        calibration=sub("calibration"),
    threads: 1
    log:
        f"{R}/logs/calibration_z.log",
    benchmark:
        f"{R}/benchmarks/calibration_z.tsv"
    conda:
        "../envs/calib.yaml"
    script:
        "../scripts/calibration_z.py"
