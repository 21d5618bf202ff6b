"""Turntable calibration methods of Liu 2021: objectives (``objectives``, eqs. 7, 25, 26), population optimisers
(``optimizers``: DE family, IDE eqs. 11-18, GA, PSO), the triad fits with standard errors (``fit``), the
identifiability SVD (``identifiability``) and the algebraic ellipsoid fit (``ellipsoid``)."""
