"""Tail probabilities and quantiles of the chi-square and F distributions, as ``scipy.stats`` computes them.

``scipy.stats.chi2.sf`` / ``.ppf`` and ``scipy.stats.f.sf`` each evaluate one special function of
``scipy.special``; called here directly, they give the same numbers to the bit (tests/core/test_distributions.py
compares them) without importing ``scipy.stats`` (~0.5 s of every process start) and without the distribution
objects' argument handling, which costs some 40 times the evaluation (the diagnosis asks for thousands).
"""
from __future__ import annotations

import numpy as np
from scipy import special


def chi2_sf(x, df) -> float:
    """Upper tail P(X > x) of the chi-square distribution with ``df`` degrees of freedom: ``scipy.stats.chi2.sf``
    (``scipy.special.chdtrc``). Below the support (x < 0): 1."""
    return 1.0 if x < 0 else float(special.chdtrc(df, x))


def f_sf(x, dfn, dfd) -> float:
    """Upper tail of the F distribution: ``scipy.stats.f.sf(x, dfn, dfd)`` (``scipy.special.fdtrc``). Below the
    support (x < 0): 1."""
    return 1.0 if x < 0 else float(special.fdtrc(dfn, dfd, x))


def chi2_ppf(q: float, df) -> np.ndarray:
    """Quantile ``q`` (0 < q < 1) of the chi-square distribution with ``df`` (> 0, array) degrees of freedom:
    ``scipy.stats.chi2.ppf(q, df)`` (``2 gammaincinv(df / 2, q)``)."""
    return 2 * special.gammaincinv(np.asarray(df, dtype=float) / 2, q)
