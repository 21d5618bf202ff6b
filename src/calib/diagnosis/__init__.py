"""Mismatch diagnosis: does the base sensor model fit a calibration recording, and if not, what is missing?

``calib diagnose RECORDING.nc --out DIR`` (:func:`diagnose`) writes ``DIR/report.json``, ``DIR/report.md`` and
figures for any ``calib-recording-1`` file that has a segment table (synthetic, or imported with detected
static segments).

Method
------
1. **Base model and goodness of fit.** Observations are window reductions of the rate readings
   (:mod:`calib.diagnosis.geometry`): static-segment means and, for rotation segments cut to whole revolutions
   with the table angle, the mean and the first table-angle harmonics. With nominal attitudes (synthetic
   sessions) the *vector* model is used (:mod:`calib.diagnosis.vector`): ``N = M x + b`` per triad (M = K E,
   Liu 2021 eqs. 1-4) with known inputs x (f = C_n^b (0, 0, g), omega = table rate + C_n^b omega_ie^n) --
   linear, 24 parameters, all identified. Without attitudes (real recordings) the *norm* model of the
   accelerometer is used (Liu 2021 eq. 7, identified lower-triangular form, :mod:`calib.diagnosis.norm`).
   The fit is generalised least squares (:mod:`calib.diagnosis.fitting`) with the covariance of the window
   means from the noise model (:mod:`calib.diagnosis.noise`: Allan deviation for white noise and
   quantisation, restricted ML of the base residuals for the slow random-walk part). chi-square per
   (sensor, axis) block and overall, with p-values; standardised residuals per segment.
2. **Locate** (:mod:`calib.diagnosis.locate`). Where the misfit lives: per (sensor, axis); per static phase
   the harmonics of the table angle (positions ``step`` apart) and the disagreement between phase means; per
   rotation pair the sum and the difference of the +/- residuals against |rate|; the phase-quadrature part
   of the gyro harmonics against rate; the time course (residual chi-square in time bins).
3. **Name.** A library of candidate terms (:mod:`calib.diagnosis.library`; the ids of :mod:`calib.sim.effects`,
   verbatim), each with its own parameters. Before fitting (:mod:`calib.diagnosis.term_identifiability`): the
   fraction of each signature the base parameters absorb (``1 - |P_perp s| / |s|``, whitened), the visible
   rank, and the smallest principal angle between the visible signatures of every pair of candidates (alias
   groups: angle < ``alias_angle_deg``). Then forward stepwise selection (:mod:`calib.diagnosis.selection`):
   the candidate with the largest BIC gain is added if its BIC gain is positive and its likelihood-ratio test
   has p < ``alpha``; repeat until nothing passes. Aliases of a found term: every other candidate that, in
   its place, gives a BIC within ``alias_delta_bic`` of the final model, or whose visible signature lies
   within ``alias_angle_deg`` of it.
4. **Model it** (:mod:`calib.diagnosis.analysis`). Refit with the selected terms: chi-square and residual RMS
   before/after, residual figures, estimates with 95 % intervals (``1.96`` standard errors of the GLS fit;
   the clock offset and the warm-up time constant of a bias drift (profiled on a grid) enter the joint
   covariance through Gauss-Newton columns at their profile optimum; the standard errors of every found
   sensor term are marginalised over the slow-noise parameters,
   :func:`calib.diagnosis.analysis.slow_se_marginal`), and how the base parameters moved (in their standard
   errors).
5. **Adequacy on the measured noise** (:mod:`calib.diagnosis.adequacy`). The noise of every window mean is
   *measured*: the Allan deviation of the session's static samples (fast noise) and, for the slow noise between
   windows, a long static record of the same unit (``noise_record`` setting, ``calib diagnose --noise-record``;
   the upper end of its 95 % Allan band); the level and slow part the search estimates from the window means,
   and the norm model's scaling to the scatter of its segment means, are reported (``overdispersion``) but never
   used to pass a test. chi-square tests of the final model on the whole record, per (sensor, axis), per segment
   class (static, rotation) and per first / last third of the session, Holm step-down at ``adequacy_alpha``.
6. **Beyond the library** (:mod:`calib.diagnosis.generic`): the residuals of the final model are tested against
   generic bases (time, scale in time, gravity direction to degree 4, rate, per-stop attitude); a library term
   is accepted as the explanation only when none stays significant. Rival forms of a found term that fit this
   path as well are reported (``form_alternatives``) with the experiment that separates them.
7. **Report** (:mod:`calib.diagnosis.report`). verdict and exit code of ``calib diagnose``: ``adequate`` (0),
   ``missing_physics`` (1: the found terms explain the data, ``explained: true``), ``unexplained`` (3: misfit
   is left after the best library model; ``unexplained[]`` says where -- sensor, axis, segment class, part of
   the session or generic family -- its size and shape), ``inconclusive`` (3: the data cannot decide, e.g. a
   misfit within what unmeasured slow noise could do, or too few segments). ``found[]``, ``absent[]`` (tested,
   with 95 % upper bounds), ``untestable[]`` (why, and the experiment that would make it testable).

The concealed-effect proof, its scoring against the truth sidecars and the real-data runs are studies
(:mod:`calib.studies.diagnosis_proof`, :mod:`calib.studies.diagnosis_score`,
:mod:`calib.studies.diagnosis_real`).
"""
from calib.diagnosis.analysis import analyse, slow_se_marginal
from calib.diagnosis.fitting import fit
from calib.diagnosis.geometry import (AXES, ROWS, SENSORS, TO_MODEL, DiagnosisInputError, Geometry, Window,
                                      base_design, build_geometry, rate_readings, reduce_data, reduced_inputs)
from calib.diagnosis.library import DRIFT_TAUS, EXPERIMENTS, Candidate, build_library, is_shape_parameter
from calib.diagnosis.locate import locate
from calib.diagnosis.noise import NoiseFit, fit_noise
from calib.diagnosis.norm import setup_norm_problem
from calib.diagnosis.problem import DEFAULT_SETTINGS, REPORT_FORMAT, Fit, Problem
from calib.diagnosis.report import (allan_figure, build_report, fmt, inconclusive_report, report_markdown,
                                    residual_figure)
from calib.diagnosis.run import diagnose, diagnose_dataset, diagnose_recording, load_for_diagnosis
from calib.diagnosis.selection import stepwise
from calib.diagnosis.vector import setup_problem

__all__ = [
    "AXES", "DEFAULT_SETTINGS", "DRIFT_TAUS", "EXPERIMENTS", "REPORT_FORMAT", "ROWS", "SENSORS", "TO_MODEL",
    "Candidate", "DiagnosisInputError", "Fit", "Geometry", "NoiseFit", "Problem", "Window",
    "allan_figure", "analyse", "base_design", "build_geometry", "build_library", "build_report", "diagnose",
    "diagnose_dataset", "diagnose_recording", "fit", "fit_noise", "fmt", "inconclusive_report",
    "is_shape_parameter", "load_for_diagnosis", "locate", "rate_readings", "reduce_data", "reduced_inputs", "report_markdown",
    "residual_figure", "setup_norm_problem", "setup_problem", "slow_se_marginal", "stepwise",
]
