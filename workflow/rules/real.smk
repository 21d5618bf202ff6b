# Real recordings: import -> static detection -> calibration without a turntable record (a study config with a
# `recording:` section; see config/real/*.yaml). The rules read only `recording` and `results`.


rule import_recording:
    input:
        settings=lambda w: config["recording"]["import"],
    output:
        recording=f"{R}/data/recording.nc",
    params:
        settings=lambda w: import_settings(),
    log:
        f"{R}/logs/import_recording.log",
    conda:
        "../envs/calib.yaml"
    script:
        "../scripts/import_recording.py"


rule fieldcal:
    input:
        recording=f"{R}/data/recording.nc",
    output:
        result=f"{R}/calibration/fieldcal.nc",
        summary=f"{R}/calibration/fieldcal.json",
        fig=report(f"{R}/calibration/static_detection.png", category="5 Real recordings", caption="../report/detection.rst"),
        metrics=f"{R}/calibration/fieldcal.metrics.json",
    params:
        settings=lambda w: config["recording"].get("fieldcal") or {},   # no key: the default settings
    log:
        f"{R}/logs/fieldcal.log",
    benchmark:
        f"{R}/benchmarks/fieldcal.tsv"
    conda:
        "../envs/calib.yaml"
    script:
        "../scripts/fieldcal.py"


rule real_drift:
    input:
        recording=f"{R}/data/recording.nc",
    output:
        result=f"{R}/drift/real_drift.json",
        fig=report(f"{R}/drift/real_drift.png", category="5 Real recordings", caption="../report/real_drift.rst"),
        metrics=f"{R}/drift/real_drift.metrics.json",
    params:
        drift=lambda w: config["recording"]["drift"],
        seed=config["seeds"]["drift"],
    threads: 2
    log:
        f"{R}/logs/real_drift.log",
    conda:
        "../envs/calib.yaml"
    script:
        "../scripts/real_drift.py"
