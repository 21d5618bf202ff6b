# calib: calibration of a strapdown INS (Liu 2021) and gyro-drift estimation (He 2019).
# Thin top level: configuration, validation, and the per-stage rule files.
from snakemake.utils import min_version, validate

min_version("9.0")


configfile: "config/config.yaml"


validate(config, "src/calib/resources/config.schema.yaml")  # package data: the CLI reads the same file


report: "workflow/report/workflow.rst"


include: "workflow/rules/common.smk"
include: "workflow/rules/data.smk"
include: "workflow/rules/calibration.smk"
include: "workflow/rules/navigation.smk"
include: "workflow/rules/drift.smk"
include: "workflow/rules/real.smk"
include: "workflow/rules/diagnosis.smk"
include: "workflow/rules/sweeps.smk"
include: "workflow/rules/track.smk"


rule all:
    input:
        all_targets(),
    default_target: True
