"""Foundations every layer may use: WGS-84 Earth model and units (``earth``), rotations (``rotations``), the
triad error model N = K E x + b and its parameter vector (``triad``, Liu 2021 eqs. 1-4 and 8), the one seed helper
(``seeds``) and console progress (``progress``). Imports nothing else of ``calib``."""
