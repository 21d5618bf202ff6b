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


# The noise-seed study's seeds in blocks of at most NOISE_SEEDS_PER_JOB (about 1.5 s of one core a seed at the
# default settings), one job each (seed_blocks in common.smk).
NOISE_SEEDS_PER_JOB = 15
NOISE_SEED_BLOCKS = seed_blocks(int(config["drift"].get("noise_seeds", 0)), NOISE_SEEDS_PER_JOB)


rule drift_noise_seeds_block:
    """A block of seeds of the noise-seed study (seeds first .. stop - 1)."""
    output:
        part=temp(f"{R}/drift/noise_seeds_parts/{{first}}_{{stop}}.json"),
    params:
        session=sub("navigation_session"),
        site=sub("site"),
        drift=sub("drift"),
        seed=session_seed(config["seeds"]["data"], "drift_noise_seeds"),
        # the block's own scratch folder (one seed's recording at a time) inside the study's, removed when empty
        workdir=lambda w, output: os.path.join(os.path.dirname(os.path.dirname(output.part)), "tmp_noise_seeds",
                                               f"{w.first}_{w.stop}"),
    wildcard_constraints:
        first="[0-9]+",
        stop="[0-9]+",
    threads: 1
    log:
        f"{R}/logs/drift_noise_seeds/{{first}}_{{stop}}.log",
    benchmark:
        f"{R}/benchmarks/drift_noise_seeds_block.{{first}}_{{stop}}.tsv"
    conda:
        "../envs/calib.yaml"
    script:
        "../scripts/drift_noise_seeds_block.py"


rule drift_noise_seeds:
    """The drift estimators over many noise seeds against the Cramér–Rao bound (gathered from the seed blocks'
    jobs; the bound is computed here, once)."""
    input:
        parts=expand(f"{R}/drift/noise_seeds_parts/{{block}}.json", block=NOISE_SEED_BLOCKS),
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
        # the study's scratch folder, which holds the blocks' own: removed here when they have left it empty
        workdir=lambda w, output: os.path.join(os.path.dirname(output.nc), "tmp_noise_seeds"),
    # the bound's QR decomposition runs in the linear-algebra library's threads, and its last bits depend on their
    # number (3 h window): the same 2 threads wherever the study runs keep its products the same
    threads: 2
    log:
        f"{R}/logs/drift_noise_seeds.log",
    benchmark:
        f"{R}/benchmarks/drift_noise_seeds.tsv"
    conda:
        "../envs/calib.yaml"
    script:
        "../scripts/drift_noise_seeds.py"
