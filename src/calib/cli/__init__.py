"""The ``calib`` command line: the same library functions as the workflow rules, for work on single files.

:mod:`calib.cli.entry` holds the parser, the exit-code contract and :func:`run` (the ``calib`` console script).
Each command group has its module -- ``simulate``, ``recordings`` (import, validate), ``calibrate`` (calibrate,
fieldcal), ``navigate``, ``diagnose``, ``noise_terms`` (noise), ``export``, ``apply`` -- with its ``register(sub)``
adding its sub-commands to the parser; what they share is in :mod:`calib.cli.shared`.
"""
from calib.cli.entry import main, run  # noqa: F401 (the console script is calib.cli:run)
