"""Package data: the study configuration schema (``config.schema.yaml``), read with ``importlib.resources``
(:func:`calib.resources.schema_path`); the workflow validates its config against the same file."""
from __future__ import annotations

import importlib.resources

SCHEMA = "config.schema.yaml"


def schema_text() -> str:
    """The study configuration schema (YAML text)."""
    return importlib.resources.files(__name__).joinpath(SCHEMA).read_text()
