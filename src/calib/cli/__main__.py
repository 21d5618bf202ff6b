"""``python -m calib.cli``: the same as the ``calib`` command."""
from calib.cli import run

run()
