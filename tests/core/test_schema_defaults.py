"""The command line fills a study config's defaults by the rule the workflow uses (snakemake's ``validate``), without
importing snakemake: the oracle is snakemake itself, on the shipped configs and on configs with keys left out."""
import copy
from pathlib import Path

import pytest
import yaml

from calib.core.errors import fill_schema_defaults

ROOT = Path(__file__).resolve().parents[2]
SCHEMA = ROOT / "src" / "calib" / "resources" / "config.schema.yaml"


def _configs():
    full = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
    yield "config.yaml", full
    yield ".test", yaml.safe_load((ROOT / ".test" / "config.yaml").read_text())
    for key in list(full)[:8]:   # one top-level group left out at a time: its defaults come from the schema
        yield f"without {key}", {k: v for k, v in full.items() if k != key}


@pytest.mark.parametrize("name,cfg", list(_configs()), ids=lambda x: x if isinstance(x, str) else "")
def test_defaults_equal_snakemake_validate(name, cfg):
    snakemake_utils = pytest.importorskip("snakemake.utils")
    by_snakemake = copy.deepcopy(cfg)
    try:
        snakemake_utils.validate(by_snakemake, str(SCHEMA))
    except Exception:   # noqa: BLE001 - a config the schema refuses: ours must refuse it too
        with pytest.raises(Exception):
            fill_schema_defaults(copy.deepcopy(cfg), yaml.safe_load(SCHEMA.read_text()))
        return
    ours = fill_schema_defaults(copy.deepcopy(cfg), yaml.safe_load(SCHEMA.read_text()))
    assert ours == by_snakemake


def test_defaults_filled_only_where_absent():
    schema = {"type": "object", "properties": {"a": {"type": "integer", "default": 3},
                                               "b": {"type": "object", "default": {},
                                                     "properties": {"c": {"type": "number", "default": 1.5}}}}}
    assert fill_schema_defaults({}, schema) == {"a": 3, "b": {"c": 1.5}}
    assert fill_schema_defaults({"a": 7, "b": {"c": 2.0}}, schema) == {"a": 7, "b": {"c": 2.0}}
