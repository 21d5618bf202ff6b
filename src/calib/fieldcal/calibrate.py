"""Field calibration of real recordings that hold no turntable record.

Without a table the orientations are unknown; what a multi-position session offers is (a) the *norm* of
the specific force at rest, which must equal local gravity, and (b) between two rests, the rotation that
the gyros integrate, which must carry the gravity direction of the first rest into that of the second.
This module implements both (the multi-position idea of IMU-TK, Tedaldi, Pretto & Menegatti, ICRA 2014,
written anew), plus the Ferraris closed form for sessions whose static positions are *labelled*
(imucal's sessions: each axis up and down, and one known turn about each axis).

Models and frames
-----------------
Raw samples are first taken to the calibration's input units: counts stay counts; physical units are
converted to SI (``m s-2``, ``rad s-1``; ``g`` = 9.80665 m s-2) and increments are divided by the sample
interval. Call that ``N`` (3-vector). Then

* accelerometer (norm method):  ``a = T_a K_a (N - b_a)`` [m s-2] with
  ``T_a = [[1, -mis_yz, mis_zy], [0, 1, -mis_zx], [0, 0, 1]]`` (upper triangular, IMU-TK's layout with its
  three lower entries fixed to zero), ``K_a = diag(gain_x, gain_y, gain_z)`` and bias ``b_a``: 9
  parameters, the most the gravity norm identifies. The columns of ``T_a`` are the sensor axes in the
  body frame, so the **body frame is defined by the accelerometer triad**: body x = accel x axis, body y
  in the plane of the accel x and y axes, body z completing a right-handed orthogonal frame (IMU-TK).
* gyroscope (gravity-direction method): ``w = T_g K_g (N - b_g)`` [rad s-1] with the full misalignment
  ``T_g = [[1, -mis_yz, mis_zy], [mis_xz, 1, -mis_zx], [-mis_xy, mis_yx, 1]]`` (6 parameters: it also
  aligns the gyro triad to the accel-defined body frame), ``K_g`` diagonal (3) and ``b_g`` from the initial
  rest (or estimated: 3 more). Rates obey the right-hand rule.
* Ferraris (labelled sessions): ``N = M f + b`` with ``f`` the specific force in the frame of the labelled
  case axes; calibration ``a = M^-1 (N - b)``; gyro ``w = M_g^-1 (N - b_g)``.

``gain`` is output unit per input unit (IMU-TK's "scale", e.g. m s-2 per count). The **scale factors**
reported are its inverse, input unit per output unit -- counts per m s-2 for raw counts, the form of the
"inverse scale factors" IMU-TK prints (414.459, 412.01, 414.649 counts per m s-2 for its Xsens data). For
Ferraris the scale factors are the row norms of ``M`` (imucal's ``K_a``).

Residuals and statistics
------------------------
* accel: per-sample norm residual ``|a| - g`` over the static samples used (all samples of each interval,
  or its first ``samples_per_interval`` as IMU-TK does), minimised by Levenberg-Marquardt
  (:func:`scipy.optimize.least_squares`, analytic Jacobian). Its RMS is what IMU-TK, imucal and
  mikoff/imu-calib report (all three fit and measure per sample; the per-interval-mean RMS is also given).
* gyro: for each pair of consecutive static intervals, the calibrated gyro is integrated over the gap
  (quaternion, classical Runge-Kutta 4 with the rate interpolated linearly between samples), the gravity
  direction of the first interval (calibrated accel mean) is carried into the second and compared with
  the one measured there: residual ``R^T u_0 - u_1`` (3 components, IMU-TK's), reported as the angle
  ``2 asin(|r| / 2)`` in degrees.
* standard errors: ``sigma^2 (J^T J)^-1`` with ``sigma^2 = SSR / (m - p)``. Samples within one static
  interval share its orientation error, so for the accel the per-sample covariance is optimistic; the
  per-interval scatter is the honest noise level (both are reported).
* identifiability: SVD of the column-scaled Jacobian (each column divided by its norm). For the accel it
  is evaluated on the interval *means* (one row per interval), so that sample noise cannot lend rank to
  orientations that were never visited. Rank = number of singular values above ``rank_rtol`` x the
  largest; the weakest direction is the right singular vector of the smallest one.

Public API: :func:`fieldcal_recording` (workflow), :func:`fit_accel_norm`, :func:`fit_gyro_directions`,
:func:`fit_ferraris`, :func:`imu_tk_intervals`, :func:`imu_tk_accel_search`, :func:`mikoff_standstill`,
:func:`norm_residual_rms`, and the result classes :class:`FieldCalResult`, :class:`TriadFit`,
:class:`Identifiability`.
"""
from __future__ import annotations

import math
import re
import time as _time
from dataclasses import dataclass, field
from pathlib import Path

import numba
import numpy as np
import xarray as xr
from scipy.optimize import least_squares

from calib.calibration.ellipsoid import fit_ellipsoid
from calib.core.triad import TriadModel
from calib.calibration.identifiability import singular_spectrum
from calib.signal import detect
from calib.core import earth
from calib.io import recording

ACCEL_NAMES = ("mis_yz", "mis_zy", "mis_zx", "gain_x", "gain_y", "gain_z", "bias_x", "bias_y", "bias_z")
GYRO_NAMES = ("mis_yz", "mis_zy", "mis_zx", "mis_xz", "mis_xy", "mis_yx", "gain_x", "gain_y", "gain_z")
BIAS_NAMES = ("bias_x", "bias_y", "bias_z")
FERRARIS_M_NAMES = tuple(f"M_{r}{c}" for r in "xyz" for c in "xyz")

#: the norm model has 9 parameters: at least 9 static orientations are needed, 12 recommended (IMU-TK's minimum)
MIN_INTERVALS = 9
RECOMMENDED_INTERVALS = 12

#: IMU-TK's defaults for its test data (apps/test_imu_calib.cpp and calibration.cpp)
IMU_TK_DEFAULTS = {"k": list(range(2, 11)), "init_samples": 5000, "window": 101, "samples_per_interval": 100,
                   "min_intervals": 12}

SETTINGS_KEYS = {"method", "gravity_m_s2", "detection", "samples_per_interval", "min_intervals",
                 "recommended_intervals", "gyro", "evaluate", "rank_rtol"}
DETECTION_KEYS_DETECT = {"rule", "window_s", "min_interval_s", "threshold", "k", "init_s", "gyro_threshold",
                         "use_gyro", "onset_factor", "floor_percentile"}
DETECTION_KEYS_IMU_TK = {"rule", "k", "init_samples", "window", "samples_per_interval", "min_intervals"}
GYRO_KEYS = {"enabled", "bias", "dt", "scale_guess"}
GYRO_BIAS_MODES = ("g_sensitive", "initial", "statics", "estimate")
EVALUATIONS = ("mikoff_standstill", "directions")


class FieldCalError(ValueError):
    """Field calibration cannot proceed; the message names the input, the problem and the fix."""


# =========================================================================== result objects


@dataclass
class Identifiability:
    """SVD of a column-scaled Jacobian: how many parameter combinations the data determine.

    ``singular_values`` are relative to the largest (descending). ``weakest`` maps each parameter name to its
    component in the right singular vector of the smallest singular value.
    """

    n_params: int
    rank: int
    singular_values: np.ndarray
    condition: float
    weakest: dict
    rtol: float
    based_on: str

    def as_dict(self) -> dict:
        top = sorted(self.weakest.items(), key=lambda kv: -abs(kv[1]))
        return {"n_params": self.n_params, "rank": self.rank, "condition": self.condition, "rtol": self.rtol,
                "singular_values_rel": [float(s) for s in self.singular_values],
                "weakest_direction": {k: round(float(v), 4) for k, v in top if abs(v) >= 0.05},
                "based_on": self.based_on}

    def describe(self) -> str:
        w = ", ".join(f"{v:+.2f} {k}" for k, v in sorted(self.weakest.items(), key=lambda kv: -abs(kv[1]))
                      if abs(v) >= 0.2)
        return (f"rank {self.rank} of {self.n_params} (rtol {self.rtol:g}; condition {self.condition:.3g}); "
                f"weakest direction {w} (relative singular value {self.singular_values[-1]:.3g})")


def identifiability(jac, names, rtol: float = 1e-6, based_on: str = "") -> Identifiability:
    """Rank, condition and weakest direction of the column-scaled Jacobian ``jac`` (rows = observations)."""
    jac = np.asarray(jac, dtype=float)
    norms = np.linalg.norm(jac, axis=0)
    scaled = jac / np.where(norms > 0, norms, 1.0)
    s_full, vt = singular_spectrum(scaled)
    rel = s_full / s_full[0] if s_full[0] > 0 else s_full
    rank = int(np.sum(rel > rtol))
    weakest = vt[-1] * (1.0 if vt[-1][np.argmax(np.abs(vt[-1]))] > 0 else -1.0)
    cond = float(s_full[0] / s_full[-1]) if s_full[-1] > 0 else math.inf
    return Identifiability(len(names), rank, rel, cond, dict(zip(names, weakest.tolist())), rtol, based_on)


@dataclass
class TriadFit:
    """Calibration of one triad: ``out = matrix @ (input_factor * raw [/ dt] - bias)``.

    ``raw`` in the recording's units (``input_units``; divided by ``dt`` first when ``input_kind`` is
    ``increment``). ``matrix`` (3x3) and ``bias`` (in the converted input units: counts, or SI) hold the
    whole calibration; ``names``/``values``/``covariance`` are the fitted parameters (see module docstring;
    ``param_units`` per parameter). ``scale_factors``: input unit per output unit (IMU-TK's inverse scale
    factors). ``residual_rms`` in ``residual_units`` over ``n_residuals`` residuals.
    """

    sensor: str
    method: str
    names: tuple
    values: np.ndarray
    covariance: np.ndarray
    param_units: tuple
    matrix: np.ndarray
    bias: np.ndarray
    input_units: str
    input_factor: float
    input_kind: str
    dt: float
    output_units: str
    scale_factors: np.ndarray
    scale_factor_std: np.ndarray
    scale_factor_units: str
    residual_rms: float
    residual_units: str
    n_residuals: int
    identifiability: Identifiability | None
    notes: list = field(default_factory=list)
    extra: dict = field(default_factory=dict)
    g_sensitivity: np.ndarray | None = None

    @property
    def std(self) -> np.ndarray:
        """Standard errors of ``values`` (NaN where unknown)."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    def param(self, name: str) -> float:
        return float(self.values[self.names.index(name)])

    def model(self) -> TriadModel:
        """This calibration as the triad model N = K E x + b of :mod:`calib.core.triad` (the one representation
        of a triad's parameters): x in ``output_units``, N in the converted input units; K E = matrix^-1."""
        conv = _input_label(self.sensor, self.input_units, self.input_kind)
        return TriadModel.from_KE(np.linalg.inv(self.matrix), self.bias, input_unit=self.output_units,
                                  output_unit=conv)

    def convert_input(self, raw) -> np.ndarray:
        """Raw samples (recording units) to the calibration's input units (counts, or SI rates)."""
        x = np.asarray(raw, dtype=np.float64) * self.input_factor
        return x / self.dt if self.input_kind == "increment" else x

    def apply(self, raw, accel_calibrated=None) -> np.ndarray:
        """Calibrated output (``output_units``, body frame) of raw (n, 3) samples in the recording's units.

        A g-sensitive gyro (``g_sensitivity`` set) also needs the calibrated specific force [m s-2] of the
        same samples: ``out = matrix @ (N - bias - G a)``.
        """
        x = self.convert_input(raw) - self.bias
        if self.g_sensitivity is not None:
            if accel_calibrated is None:
                raise FieldCalError(f"{self.sensor} calibration is g-sensitive: pass accel_calibrated (m s-2)")
            x = x - np.asarray(accel_calibrated, dtype=float) @ self.g_sensitivity.T
        return x @ self.matrix.T


@dataclass
class FieldCalResult:
    """Field calibration of one recording. See the module docstring for frames, models and units.

    ``apply(accel_raw, gyro_raw)`` gives calibrated specific force [m s-2] and rate [rad s-1] in the body
    frame stated by ``frame``. ``metrics``: the key numbers (also in :meth:`summary`).
    """

    method: str
    accel: TriadFit
    gyro: TriadFit | None
    frame: str
    gravity_m_s2: float
    intervals: np.ndarray
    detection_rule: str
    source: str
    sensor: str
    metrics: dict
    notes: list
    settings: dict

    def apply(self, accel_raw, gyro_raw=None):
        a = self.accel.apply(accel_raw)
        if gyro_raw is None:
            return a
        if self.gyro is None:
            raise FieldCalError(f"{self.source}: no gyro calibration in this result (gyro.enabled was false)")
        return a, self.gyro.apply(gyro_raw, a)

    @property
    def how_to_apply(self) -> str:
        g = ""
        if self.gyro is not None:
            g = "; gyro [rad s-1] = gyro_matrix @ (gyro_input_factor * raw_gyro - gyro_bias" + \
                (" - gyro_g_sensitivity @ accel)" if self.gyro.g_sensitivity is not None else ")")
        return ("accel [m s-2] = accel_matrix @ (accel_input_factor * raw_accel - accel_bias)" + g +
                " (raw in the recording's units, increments divided by the sample interval first; bias in "
                "the converted input units: counts, or SI)")

    def summary(self) -> dict:
        """Key metrics as a JSON-ready dict."""
        a = self.accel
        out = {"method": self.method, "source": self.source, "sensor": self.sensor,
               "gravity_m_s2": self.gravity_m_s2, "n_static_intervals": int(len(self.intervals)),
               "detection_rule": self.detection_rule,
               "accel_norm_rms_m_s2": a.residual_rms,
               "accel_scale_factors": [float(v) for v in a.scale_factors],
               "accel_scale_factor_std": [float(v) for v in a.scale_factor_std],
               "accel_scale_factor_units": a.scale_factor_units,
               "accel_identifiability": a.identifiability.as_dict() if a.identifiability else None}
        if self.gyro is not None:
            g = self.gyro
            out.update({"gyro_residual_rms": g.residual_rms, "gyro_residual_units": g.residual_units,
                        "gyro_scale_factors": [float(v) for v in g.scale_factors],
                        "gyro_scale_factor_units": g.scale_factor_units,
                        "gyro_identifiability": g.identifiability.as_dict() if g.identifiability else None})
        out.update(self.metrics)
        out["notes"] = list(self.notes) + [f"accel: {n}" for n in a.notes] + \
            ([f"gyro: {n}" for n in self.gyro.notes] if self.gyro else [])
        return out

    def to_dataset(self) -> xr.Dataset:
        """The calibration as an ``xarray.Dataset`` with labelled dims ``parameter`` (and ``parameter_b`` for
        the covariance), ``axis_out``/``axis_in`` for the matrices, ``interval``/``bound`` for the static
        intervals. Accel and gyro parameters are prefixed ``accel.``/``gyro.``; their cross-covariance is
        not estimated (the gyro fit takes the accel calibration as fixed) and is stored as NaN.
        """
        fits = [f for f in (self.accel, self.gyro) if f is not None]
        names = [f"{f.sensor}.{n}" for f in fits for n in f.names]
        units = [u for f in fits for u in f.param_units]
        vals = np.concatenate([f.values for f in fits])
        p = len(names)
        cov = np.full((p, p), np.nan)
        i0 = 0
        for f in fits:
            k = len(f.names)
            cov[i0:i0 + k, i0:i0 + k] = f.covariance
            i0 += k
        data = {
            "value": (("parameter",), vals, {"long_name": "fitted parameter (see units)"}),
            "standard_error": (("parameter",), np.sqrt(np.clip(np.diag(cov), 0, None)),
                               {"long_name": "1-sigma standard error (NaN: not estimated)"}),
            "units": (("parameter",), np.asarray(units, dtype=str)),
            "covariance": (("parameter", "parameter_b"), cov,
                           {"long_name": "parameter covariance; accel-gyro cross terms not estimated (NaN)"}),
            "static_intervals": (("interval", "bound"), np.asarray(self.intervals, dtype=np.int64).reshape(-1, 2),
                                 {"long_name": "static intervals [start, stop) in samples"}),
        }
        for f in fits:
            s = f.sensor
            data[f"{s}_matrix"] = (("axis_out", "axis_in"), f.matrix,
                                   {"long_name": f"{s} calibration matrix", "units": f"{f.output_units} per input unit"})
            data[f"{s}_bias"] = (("axis_in",), f.bias, {"long_name": f"{s} bias in the converted input units",
                                                        "units": _converted_units(f)})
            data[f"{s}_scale_factor"] = (("axis_in",), f.scale_factors,
                                         {"units": f.scale_factor_units, "long_name": f"{s} scale factors "
                                          "(input per output unit; IMU-TK's inverse scale factors)"})
            data[f"{s}_scale_factor_std"] = (("axis_in",), f.scale_factor_std, {"units": f.scale_factor_units})
            if f.g_sensitivity is not None:
                data[f"{s}_g_sensitivity"] = (("axis_in", "accel_axis"), f.g_sensitivity,
                                              {"units": f"{_converted_units(f)} per m s-2",
                                               "long_name": "offset per unit calibrated specific force"})
        coords = {"parameter": names, "parameter_b": names, "axis_out": list("xyz"), "axis_in": list("xyz"),
                  "accel_axis": list("xyz"),
                  "bound": ["start", "stop"]}
        attrs = {"conventions": "calib-fieldcal-1", "method": self.method, "frame": self.frame,
                 "how_to_apply": self.how_to_apply, "gravity_m_s2": self.gravity_m_s2, "source": self.source,
                 "sensor": self.sensor, "detection_rule": self.detection_rule,
                 "notes": " | ".join(self.summary()["notes"])}
        for f in fits:
            s = f.sensor
            attrs.update({f"{s}_input_units": f.input_units, f"{s}_input_factor": f.input_factor,
                          f"{s}_input_kind": f.input_kind, f"{s}_output_units": f.output_units,
                          f"{s}_method": f.method, f"{s}_residual_rms": f.residual_rms,
                          f"{s}_residual_units": f.residual_units, f"{s}_n_residuals": f.n_residuals})
            if f.identifiability is not None:
                idf = f.identifiability
                attrs.update({f"{s}_rank": idf.rank, f"{s}_n_params": idf.n_params,
                              f"{s}_condition": idf.condition, f"{s}_identifiability": idf.describe()})
        for k, v in self.metrics.items():
            if isinstance(v, (int, float, str, np.integer, np.floating)) and not isinstance(v, bool):
                attrs[f"metric_{k}"] = v
        return xr.Dataset(data, coords=coords, attrs=attrs)


def _converted_units(f: TriadFit) -> str:
    if f.input_units == "count":
        return "count" if f.input_kind == "rate" else "count s-1"
    return "m s-2" if f.sensor == "accel" else "rad s-1"


# =========================================================================== models


def misalignment_matrix(p6) -> np.ndarray:
    """IMU-TK's misalignment matrix from ``(mis_yz, mis_zy, mis_zx, mis_xz, mis_xy, mis_yx)``:
    ``[[1, -yz, zy], [xz, 1, -zx], [-xy, yx, 1]]`` (columns: sensor axes in the body frame, small angles)."""
    yz, zy, zx, xz, xy, yx = p6
    return np.array([[1.0, -yz, zy], [xz, 1.0, -zx], [-xy, yx, 1.0]])


def accel_matrix(p) -> np.ndarray:
    """``T_a K_a`` of the 9-parameter norm model (order :data:`ACCEL_NAMES`)."""
    return misalignment_matrix([p[0], p[1], p[2], 0.0, 0.0, 0.0]) * np.asarray(p[3:6])[None, :]


def _accel_apply(p, N):
    return (N - p[6:9]) @ accel_matrix(p).T


def _accel_residual(p, N, g):
    return np.linalg.norm(_accel_apply(p, N), axis=1) - g


def _accel_jacobian(p, N, g):
    """d(|a| - g)/dp for the 9-parameter model; rows = samples, columns = :data:`ACCEL_NAMES`."""
    d = N - p[6:9]
    u = d * p[3:6]
    T = misalignment_matrix([p[0], p[1], p[2], 0.0, 0.0, 0.0])
    x = u @ T.T
    n = x / np.linalg.norm(x, axis=1)[:, None]
    nT = n @ T  # (n^T T)_i
    J = np.empty((len(N), 9))
    J[:, 0] = -n[:, 0] * u[:, 1]
    J[:, 1] = n[:, 0] * u[:, 2]
    J[:, 2] = -n[:, 1] * u[:, 2]
    J[:, 3:6] = nT * d
    J[:, 6:9] = -nT * p[3:6]
    return J


def ellipsoid_guess(means, g: float):
    """Initial 9 parameters from an algebraic ellipsoid fit to static means (>= 9, spread over orientations).

    :func:`calib.calibration.ellipsoid.fit_ellipsoid`, then the centre as the bias and the upper-triangular
    Cholesky factor of the normalised ``Q`` as ``T_a K_a``. Returns None when
    the quadric is not an ellipsoid (then use :func:`range_guess`).
    """
    fit = fit_ellipsoid(means)
    if fit is None:
        return None
    Qn, s0 = fit.Qn, fit.s0
    L = np.linalg.cholesky(Qn)  # Qn = L L^T, L lower -> R = L^T upper with R^T R = Qn
    R = L.T * (g / s0)
    k = np.diag(R).copy()
    T = R / k[None, :]
    return np.array([-T[0, 1], T[0, 2], -T[1, 2], k[0], k[1], k[2], *fit.bias])


def range_guess(samples, g: float):
    """Crude initial parameters: bias = midpoint of the extremes, gain = 2 g / range, no misalignment."""
    s = np.asarray(samples, dtype=float)
    lo, hi = s.min(axis=0), s.max(axis=0)
    rng = np.where(hi - lo > 0, hi - lo, 1.0)
    return np.array([0.0, 0.0, 0.0, *(2.0 * g / rng), *((lo + hi) / 2.0)])


# =========================================================================== accelerometer: gravity norm


def _select_samples(x, intervals, n_per):
    iv = np.asarray(intervals, dtype=np.int64).reshape(-1, 2)
    if n_per is None:
        return np.concatenate([x[a:b] for a, b in iv]), np.concatenate(
            [np.full(b - a, i) for i, (a, b) in enumerate(iv)])
    short = [(a, b) for a, b in iv if b - a < n_per]
    if short:
        raise FieldCalError(f"samples_per_interval={n_per} but interval(s) {short[:3]} are shorter -- fix: drop "
                            "short intervals (min_interval_s) or lower samples_per_interval")
    return np.concatenate([x[a:a + n_per] for a, b in iv]), np.repeat(np.arange(len(iv)), n_per)


def _require_intervals(n_found, needed, recommended, detection, path, what="static intervals"):
    """Raise the too-few error (with a threshold suggestion from ``detection``) or return a note."""
    if n_found < needed:
        if detection is not None:
            raise detect.too_few_static_error(needed, n_found, detection.threshold, rule=detection.rule,
                                              suggestion=detection.suggest_threshold(needed), path=path,
                                              min_interval_s=detection.min_samples / detection.fs, k=detection.k)
        raise FieldCalError(f"{path or 'input'}: {n_found} {what} given, the 9-parameter norm model needs at "
                            f"least {needed} (recommended {recommended}) -- fix: record more static positions "
                            "or lower the detection threshold (detect.StaticDetection.suggest_threshold)")
    if n_found < recommended:
        msg = f"only {n_found} {what} (>= {needed} needed, >= {recommended} recommended)"
        if detection is not None:
            sug = detection.suggest_threshold(recommended)
            if sug is not None:
                msg += f"; threshold={sug:.4g} in detect_static would give {recommended}"
        return msg
    return None


def fit_accel_norm(accel, intervals, gravity: float, *, samples_per_interval: int | None = None, x0=None,
                   input_units: str = "count", input_factor: float = 1.0, input_kind: str = "rate",
                   dt: float = 1.0, min_intervals: int = MIN_INTERVALS,
                   recommended_intervals: int = RECOMMENDED_INTERVALS, rank_rtol: float = 1e-6,
                   detection: detect.StaticDetection | None = None, path=None) -> TriadFit:
    """Accelerometer calibration by the gravity norm at static intervals (9-parameter model).

    ``accel``: (n, 3) samples in the calibration's input units (counts, or m s-2 -- already converted).
    ``intervals``: (m, 2) ``[start, stop)`` static sample ranges. ``gravity``: local gravity [m s-2].
    ``samples_per_interval``: use only the first n samples of each interval (IMU-TK: 100); None = all.
    ``x0``: initial parameters (:data:`ACCEL_NAMES` order); default: ellipsoid fit to the interval means.
    Raises a :class:`detect.StaticDetectionError` (with a threshold suggestion when ``detection`` is given)
    for fewer than ``min_intervals`` intervals. ``input_*``/``dt``: how raw recording samples map to the input
    units (stored for :meth:`TriadFit.apply`).
    """
    accel = np.asarray(accel, dtype=np.float64)
    iv = np.asarray(intervals, dtype=np.int64).reshape(-1, 2)
    notes = []
    note = _require_intervals(len(iv), min_intervals, recommended_intervals, detection, path)
    if note:
        notes.append(note)
    N, which = _select_samples(accel, iv, samples_per_interval)
    means = np.array([accel[a:b].mean(axis=0) for a, b in iv])
    if x0 is None:
        x0 = ellipsoid_guess(means, gravity)
        if x0 is None:
            x0 = range_guess(means, gravity)
            notes.append("initial guess from the range of the static means (ellipsoid fit not positive definite)")
        else:
            notes.append("initial guess from an algebraic ellipsoid fit to the static means")
    x0 = np.asarray(x0, dtype=float)
    sol = least_squares(_accel_residual, x0, jac=_accel_jacobian, args=(N, gravity), method="lm",
                        x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12)
    p = sol.x
    if p[5] < 0 or p[4] < 0 or p[3] < 0:  # a sign flip of one axis gives the same norms: fix the gauge
        flip = np.sign(p[3:6])
        p = p.copy()
        p[3:6] *= flip
        # T' = D T D with D = diag(flip): entry (i, j) changes sign with d_i d_j; the output frame is D x the old
        p[0] *= flip[0] * flip[1]
        p[1] *= flip[0] * flip[2]
        p[2] *= flip[1] * flip[2]
        notes.append("gain signs fixed positive (the norm does not see axis sign)")
    r = _accel_residual(p, N, gravity)
    J = _accel_jacobian(p, N, gravity)
    m, k = J.shape
    dof = max(m - k, 1)
    sigma2 = float(r @ r) / dof
    cov = sigma2 * np.linalg.pinv(J.T @ J)
    ident = identifiability(_accel_jacobian(p, means, gravity), ACCEL_NAMES, rank_rtol,
                            based_on=f"interval means ({len(iv)} rows)")
    if ident.rank < 9:
        notes.append(f"norm model not fully identified: {ident.describe()}")
    gains = p[3:6]
    sf = 1.0 / gains
    sf_std = np.sqrt(np.diag(cov)[3:6]) / gains ** 2
    cal_means = _accel_apply(p, means)
    mean_res = np.linalg.norm(cal_means, axis=1) - gravity
    in_u = _input_label("accel", input_units, input_kind)
    sf_units = _sf_units("accel", input_units, in_u)
    return TriadFit(
        sensor="accel", method="gravity_norm", names=ACCEL_NAMES, values=p, covariance=cov,
        param_units=("rad", "rad", "rad", f"m s-2 per {in_u}", f"m s-2 per {in_u}", f"m s-2 per {in_u}",
                     in_u, in_u, in_u),
        matrix=accel_matrix(p), bias=p[6:9].copy(), input_units=input_units, input_factor=float(input_factor),
        input_kind=input_kind, dt=float(dt), output_units="m s-2", scale_factors=sf, scale_factor_std=sf_std,
        scale_factor_units=sf_units, residual_rms=float(np.sqrt(np.mean(r * r))), residual_units="m s-2",
        n_residuals=int(m), identifiability=ident, notes=notes,
        extra={"interval_norm_residuals": mean_res, "interval_norm_rms": float(np.sqrt(np.mean(mean_res ** 2))),
               "sigma": math.sqrt(sigma2), "n_intervals": int(len(iv)), "samples_per_interval": samples_per_interval,
               "x0": x0, "nfev": int(sol.nfev), "residuals": r, "residual_interval": which})


def _sf_units(sensor, units, in_label):
    out = "m s-2" if sensor == "accel" else "rad s-1"
    return f"{in_label} per {out}" if units == "count" else f"1 (input in {out} per {out})"


def _input_label(sensor, units, kind):
    if units == "count":
        return "count" if kind == "rate" else "count s-1"
    return "m s-2" if sensor == "accel" else "rad s-1"


def norm_residual_rms(accel_calibrated, gravity: float, intervals=None, mask=None,
                      samples_per_interval: int | None = None) -> float:
    """Per-sample RMS of ``|a| - g`` [m s-2] over static ``intervals`` (optionally their first n samples)
    or a boolean ``mask`` of static samples: how IMU-TK, imucal and mikoff/imu-calib measure it."""
    a = np.asarray(accel_calibrated, dtype=float)
    if mask is not None:
        x = a[np.asarray(mask, dtype=bool)]
    else:
        x, _ = _select_samples(a, intervals, samples_per_interval)
    r = np.linalg.norm(x, axis=1) - gravity
    return float(np.sqrt(np.mean(r * r)))


# =========================================================================== reference selection rules


def imu_tk_intervals(accel, fs: float, k: float, *, init_samples: int = 5000, window: int = 101,
                     samples_per_interval: int = 100) -> np.ndarray:
    """Static intervals as IMU-TK selects them (accelerometer only).

    Threshold ``k`` x the variance magnitude of samples ``[0, init_samples]`` (inclusive, as IMU-TK's
    ``DataInterval(0, n_init)``); centred window of ``window`` samples; IMU-TK scans only the samples with a
    full window, so an interval starts no earlier than ``window // 2`` and one still open at the end stops at
    ``n - window // 2 - 1``; intervals with ``stop - start < samples_per_interval`` are dropped. Returns
    ``[start, stop)`` pairs (``stop`` = IMU-TK's ``end_idx``, the first non-static sample).
    """
    accel = np.asarray(accel, dtype=np.float64)
    n = len(accel)
    h = window // 2
    thr = k * detect.variance_norm(accel[:init_samples + 1])
    s = detect.moving_variance_norm(accel, window)
    iv = detect.runs(s < thr)
    if len(iv) == 0:
        return iv
    iv[:, 0] = np.maximum(iv[:, 0], h)
    iv[:, 1] = np.minimum(iv[:, 1], n - h - 1)
    return iv[(iv[:, 1] - iv[:, 0]) >= samples_per_interval]


def imu_tk_accel_search(accel, fs: float, gravity: float, *, k=None, init_samples: int = 5000, window: int = 101,
                        samples_per_interval: int = 100, min_intervals: int = 12, **fit_kwargs):
    """IMU-TK's accelerometer procedure: for each threshold multiplier in ``k`` (default 2..10), intervals by
    :func:`imu_tk_intervals`, a norm fit on the first ``samples_per_interval`` samples of each (skipped when
    fewer than ``min_intervals``); keeps the multiplier with the smallest final cost (1/2 SSR).

    Returns ``(fit, k_chosen, intervals, table)``; ``table`` lists (k, n_intervals, cost, rms) per multiplier.
    """
    ks = IMU_TK_DEFAULTS["k"] if k is None else ([k] if np.ndim(k) == 0 else list(k))
    best, table = None, []
    for kk in ks:
        iv = imu_tk_intervals(accel, fs, kk, init_samples=init_samples, window=window,
                              samples_per_interval=samples_per_interval)
        if len(iv) < min_intervals:
            table.append((kk, len(iv), None, None))
            continue
        fit = fit_accel_norm(accel, iv, gravity, samples_per_interval=samples_per_interval,
                             min_intervals=min(min_intervals, MIN_INTERVALS), **fit_kwargs)
        cost = 0.5 * fit.residual_rms ** 2 * fit.n_residuals
        table.append((kk, len(iv), cost, fit.residual_rms))
        if best is None or cost < best[0]:
            best = (cost, fit, kk, iv)
    if best is None:
        raise detect.StaticDetectionError(
            f"IMU-TK rule: no threshold multiplier in {ks} gives {min_intervals} intervals of "
            f"{samples_per_interval} samples (found {[t[1] for t in table]}) -- fix: larger multipliers, a "
            "longer initial rest (init_samples) or more static positions")
    return best[1], best[2], best[3], table


def mikoff_standstill(gyro_rad_s, threshold: float = 0.13, guard: int = 60) -> np.ndarray:
    """Standstill flags as mikoff/imu-calib's ``generate_standstill_flags`` sets them (reimplemented).

    A sample is quiet when ``|w| < threshold`` [rad s-1]. It is a standstill sample when it is quiet, more than
    ``guard`` samples have passed since the last non-quiet sample (none before counts as passed), and no
    non-quiet sample with index >= ``guard`` follows within ``guard`` samples (the tool clears the ``guard``
    samples before each motion; its slice does nothing for motions earlier than ``guard``).
    """
    w = np.asarray(gyro_rad_s, dtype=float)
    n = len(w)
    motion = ~(np.linalg.norm(w, axis=1) < threshold)
    idx = np.arange(n)
    last = np.maximum.accumulate(np.where(motion, idx, -1))
    ok_after = (last < 0) | (idx - last > guard)
    mot_late = motion & (idx >= guard)
    nxt = np.where(mot_late, idx, n + 10 * guard)
    nxt = np.minimum.accumulate(nxt[::-1])[::-1]
    # the next late motion strictly after i
    nxt_after = np.concatenate([nxt[1:], [n + 10 * guard]])
    ok_before = (nxt_after - idx) > guard
    return (~motion) & ok_after & ok_before


# =========================================================================== gyroscope: gravity directions


@numba.njit(cache=True, inline="always")
def _qdot(q0, q1, q2, q3, wx, wy, wz):
    """0.5 q (x) (0, w): body-rate kinematics of q = C_b(t)^b(0), scalar first."""
    return (-0.5 * (q1 * wx + q2 * wy + q3 * wz),
            0.5 * (q0 * wx + q2 * wz - q3 * wy),
            0.5 * (q0 * wy - q1 * wz + q3 * wx),
            0.5 * (q0 * wz + q1 * wy - q2 * wx))


@numba.njit(cache=True)
def integrate_quaternions(w, dt, starts, stops):
    """Integrate body rates ``w`` (n, 3) [rad s-1] over index ranges: for each m, steps ``j = starts[m] ..
    stops[m] - 1`` from sample j to j+1 of length ``dt[j]`` [s]; classical RK4 with the rate linear between
    samples; quaternion renormalised each step. Returns (m, 4) scalar-first quaternions ``C_b(end)^b(start)``.
    """
    m = starts.shape[0]
    out = np.empty((m, 4))
    for i in range(m):
        q0, q1, q2, q3 = 1.0, 0.0, 0.0, 0.0
        for j in range(starts[i], stops[i]):
            h = dt[j]
            ax, ay, az = w[j, 0], w[j, 1], w[j, 2]
            bx, by, bz = w[j + 1, 0], w[j + 1, 1], w[j + 1, 2]
            mx, my, mz = 0.5 * (ax + bx), 0.5 * (ay + by), 0.5 * (az + bz)
            k10, k11, k12, k13 = _qdot(q0, q1, q2, q3, ax, ay, az)
            k20, k21, k22, k23 = _qdot(q0 + 0.5 * h * k10, q1 + 0.5 * h * k11, q2 + 0.5 * h * k12,
                                       q3 + 0.5 * h * k13, mx, my, mz)
            k30, k31, k32, k33 = _qdot(q0 + 0.5 * h * k20, q1 + 0.5 * h * k21, q2 + 0.5 * h * k22,
                                       q3 + 0.5 * h * k23, mx, my, mz)
            k40, k41, k42, k43 = _qdot(q0 + h * k30, q1 + h * k31, q2 + h * k32, q3 + h * k33, bx, by, bz)
            c = h / 6.0
            q0 = q0 + c * (k10 + 2.0 * k20 + 2.0 * k30 + k40)
            q1 = q1 + c * (k11 + 2.0 * k21 + 2.0 * k31 + k41)
            q2 = q2 + c * (k12 + 2.0 * k22 + 2.0 * k32 + k42)
            q3 = q3 + c * (k13 + 2.0 * k23 + 2.0 * k33 + k43)
            nq = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
            q0, q1, q2, q3 = q0 / nq, q1 / nq, q2 / nq, q3 / nq
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = q0, q1, q2, q3
    return out


def quats_to_dcm(q) -> np.ndarray:
    """(m, 4) scalar-first unit quaternions to (m, 3, 3) DCMs (same rotation as :func:`transforms.quat_to_dcm`)."""
    q = np.asarray(q, dtype=float)
    q0, q1, q2, q3 = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    R = np.empty((len(q), 3, 3))
    R[:, 0, 0] = q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3
    R[:, 0, 1] = 2 * (q1 * q2 - q0 * q3)
    R[:, 0, 2] = 2 * (q1 * q3 + q0 * q2)
    R[:, 1, 0] = 2 * (q1 * q2 + q0 * q3)
    R[:, 1, 1] = q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3
    R[:, 1, 2] = 2 * (q2 * q3 - q0 * q1)
    R[:, 2, 0] = 2 * (q1 * q3 - q0 * q2)
    R[:, 2, 1] = 2 * (q2 * q3 + q0 * q1)
    R[:, 2, 2] = q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3
    return R


class _GyroProblem:
    """Pre-cut data of the gravity-direction fit: motion samples between consecutive statics."""

    def __init__(self, gyro, accel_cal, intervals, dt, bias0, g_sensitivity=None):
        iv = np.asarray(intervals, dtype=np.int64).reshape(-1, 2)
        u = np.array([accel_cal[a:b].mean(axis=0) for a, b in iv])
        self.u = u / np.linalg.norm(u, axis=1)[:, None]
        # gap between interval i and i+1: from its last static sample to the next one's first
        spans = [(iv[i, 1] - 1, iv[i + 1, 0]) for i in range(len(iv) - 1)]
        idx = np.concatenate([np.arange(a, b + 1) for a, b in spans])
        lens = np.array([b - a + 1 for a, b in spans])
        self.starts = np.concatenate([[0], np.cumsum(lens)[:-1]]).astype(np.int64)
        self.stops = (self.starts + lens - 1).astype(np.int64)
        self.raw = np.ascontiguousarray(gyro[idx], dtype=np.float64)
        self.dt = np.ascontiguousarray(dt[idx], dtype=np.float64)
        self.bias0 = np.asarray(bias0, dtype=float)
        # offsets removed before calibration: the bias, plus G a for a g-sensitive gyro (a: calibrated accel)
        self.offset = np.broadcast_to(self.bias0, self.raw.shape).copy()
        if g_sensitivity is not None:
            self.offset += accel_cal[idx] @ np.asarray(g_sensitivity, dtype=float).T
        self.n_pairs = len(spans)
        self.spans = spans

    def rotations(self, matrix, dbias):
        """Rotation over each gap for calibration ``matrix`` and a bias correction ``dbias`` [input units]."""
        w = np.ascontiguousarray((self.raw - self.offset - dbias) @ matrix.T)
        return quats_to_dcm(integrate_quaternions(w, self.dt, self.starts, self.stops))

    def residual_vectors(self, matrix, dbias=0.0):
        R = self.rotations(matrix, dbias)
        carried = np.einsum("mji,mj->mi", R, self.u[:-1])  # R^T u0
        return carried - self.u[1:]


def direction_angles_deg(res_vectors) -> np.ndarray:
    """Angle [deg] between two unit vectors whose difference is ``res_vectors`` (m, 3)."""
    c = np.clip(np.linalg.norm(res_vectors, axis=1) / 2.0, 0.0, 1.0)
    return np.degrees(2.0 * np.arcsin(c))


def gyro_static_regression(gyro, accel_calibrated, intervals, rank_rtol: float = 1e-6):
    """Orientation-dependent gyro offset from the static intervals: ``mean gyro = b + G a`` (least squares).

    ``gyro``: (n, 3) input units; ``accel_calibrated``: (n, 3) [m s-2]; one equation triple per interval
    (means). Returns a dict: ``bias`` (3,) [input units], ``G`` (3, 3) [input units per m s-2] (the gyro's
    g-sensitivity, imucal's ``K_ga``), ``covariance`` (12, 12) of ``(bias, G row-major)``, ``rms`` of the
    interval-mean residuals [input units] and the rank of the design ``[1, a]`` (4 needed).
    """
    iv = np.asarray(intervals, dtype=np.int64).reshape(-1, 2)
    gm = np.array([gyro[a:b].mean(axis=0) for a, b in iv])
    am = np.array([accel_calibrated[a:b].mean(axis=0) for a, b in iv])
    X = np.column_stack([np.ones(len(am)), am])
    ident = identifiability(X, ("1", "a_x", "a_y", "a_z"), rank_rtol, based_on="static means design [1, a]")
    coef, *_ = np.linalg.lstsq(X, gm, rcond=None)  # (4, 3): column j = [b_j, G_j,:]
    res = gm - X @ coef
    dof = max(len(gm) - 4, 1)
    s2 = (res * res).sum(axis=0) / dof
    XtXi = np.linalg.pinv(X.T @ X)
    cov = np.zeros((12, 12))
    for j in range(3):  # bias_j -> index j; G[j, :] -> 3 + 3 j ..
        ids = [j, 3 + 3 * j, 4 + 3 * j, 5 + 3 * j]
        cov[np.ix_(ids, ids)] = s2[j] * XtXi
    return {"bias": coef[0].copy(), "G": coef[1:].T.copy(), "covariance": cov,
            "rms": np.sqrt((res * res).mean(axis=0)), "rank": ident.rank, "identifiability": ident,
            "spread": gm.std(axis=0, ddof=1) if len(gm) > 1 else np.zeros(3)}


GSENS_NAMES = tuple(f"gsens_{r}{c}" for r in "xyz" for c in "xyz")


def fit_gyro_directions(gyro, accel_calibrated, intervals, dt, *, bias, g_sensitivity=None,
                        offset_covariance=None, estimate_bias: bool = False, scale_guess: float | None = None,
                        input_units: str = "count", input_factor: float = 1.0, input_kind: str = "rate",
                        sample_dt: float = 1.0, rank_rtol: float = 1e-6, path=None) -> TriadFit:
    """Gyro calibration from gravity directions across the motions between consecutive static intervals.

    ``gyro``: (n, 3) in the calibration's input units (counts, or rad s-1). ``accel_calibrated``: (n, 3)
    [m s-2] in the body frame. ``intervals``: (m, 2) ``[start, stop)``. ``dt``: (n,) step from each sample to
    the next [s]. ``bias``: gyro bias [input units] (e.g. the initial-rest mean). ``g_sensitivity``: optional
    (3, 3) ``G`` [input units per m s-2]: the offset removed is then ``bias + G a`` (see
    :func:`gyro_static_regression`); ``offset_covariance`` (12, 12) its covariance, stored with the result.
    ``estimate_bias``: refine the bias (3 more parameters). ``scale_guess``: input units per rad s-1 to start
    from; None: 1 for physical units, for counts the best of a logarithmic scan over 1e0..1e7.
    Minimises IMU-TK's residual ``R^T u0 - u1`` with Levenberg-Marquardt (parameters internally relative:
    gain = g0 (1 + d), bias correction = beta / g0 with beta in rad s-1).
    """
    gyro = np.asarray(gyro, dtype=np.float64)
    iv = np.asarray(intervals, dtype=np.int64).reshape(-1, 2)
    if len(iv) < 4:
        raise FieldCalError(f"{path or 'input'}: {len(iv)} static intervals give {max(len(iv) - 1, 0)} motions; the "
                            "gyro fit (9 parameters, 3 residuals per motion) needs at least 4 intervals -- fix: "
                            "record more positions or lower the detection threshold")
    prob = _GyroProblem(gyro, accel_calibrated, iv, np.asarray(dt, dtype=float), bias, g_sensitivity)
    notes = []
    if scale_guess is None:
        if input_units == "count":
            grid = np.logspace(0, 7, 141)
            costs = []
            for s in grid:
                rv = prob.residual_vectors(np.eye(3) / s)
                costs.append(float(np.sum(rv * rv)))
            scale_guess = float(grid[int(np.argmin(costs))])
            notes.append(f"initial scale {scale_guess:.4g} counts per rad s-1 from a logarithmic scan")
        else:
            scale_guess = 1.0
    g0 = 1.0 / scale_guess
    nb = 3 if estimate_bias else 0

    def unpack(q):
        gains = g0 * (1.0 + q[6:9])
        db = q[9:12] / g0 if nb else np.zeros(3)
        return misalignment_matrix(q[:6]) * gains[None, :], gains, db

    def fun(q):
        M, _, db = unpack(q)
        return prob.residual_vectors(M, db).ravel()

    q0 = np.zeros(9 + nb)
    before = direction_angles_deg(fun(q0).reshape(-1, 3))
    sol = least_squares(fun, q0, method="lm", xtol=1e-12, ftol=1e-12, gtol=1e-12)
    q = sol.x
    M, gains, db = unpack(q)
    b = prob.bias0 + db
    rv = sol.fun.reshape(-1, 3)
    ang = direction_angles_deg(rv)
    J = sol.jac
    m, k = J.shape
    dof = max(m - k, 1)
    sigma2 = float(sol.fun @ sol.fun) / dof
    cov_int = sigma2 * np.linalg.pinv(J.T @ J)
    # external parameters: mis (same), gains = g0 (1 + d), bias correction = beta / g0
    A = np.diag(np.concatenate([np.ones(6), np.full(3, g0), np.full(nb, 1.0 / g0)]))
    cov_fit = A @ cov_int @ A.T
    fit_names = GYRO_NAMES + (BIAS_NAMES if nb else ())
    ident = identifiability(J, fit_names, rank_rtol, based_on=f"gravity-direction residuals ({prob.n_pairs} motions)")
    if ident.rank < len(fit_names):
        notes.append(f"gyro model not fully identified: {ident.describe()}")
    # parameter vector: the direction fit, then the offsets (bias always; G when g-sensitive)
    names = GYRO_NAMES + BIAS_NAMES + (GSENS_NAMES if g_sensitivity is not None else ())
    values = np.concatenate([q[:6], gains, b] + ([np.asarray(g_sensitivity, float).ravel()]
                                                if g_sensitivity is not None else []))
    p = len(names)
    cov = np.zeros((p, p))
    cov[:9, :9] = cov_fit[:9, :9]
    cov[9:, :] = np.nan  # offsets taken as known in the direction fit: their uncertainty only if given
    cov[:, 9:] = np.nan
    if offset_covariance is not None:
        cov[9:, 9:] = 0.0
        oc = np.asarray(offset_covariance, dtype=float)
        k_off = oc.shape[0]
        cov[9:9 + k_off, 9:9 + k_off] = oc[:p - 9, :p - 9] if k_off >= p - 9 else oc
    if nb:
        cov[9:12, 9:12] = np.nan_to_num(cov[9:12, 9:12]) + cov_fit[9:12, 9:12]
        cov[:9, 9:12] = cov_fit[:9, 9:12]
        cov[9:12, :9] = cov_fit[9:12, :9]
    in_u = _input_label("gyro", input_units, input_kind)
    sf = 1.0 / gains
    sf_std = np.sqrt(np.diag(cov)[6:9]) / gains ** 2
    return TriadFit(
        sensor="gyro", method="gravity_direction", names=names, values=values, covariance=cov,
        param_units=("rad",) * 6 + (f"rad s-1 per {in_u}",) * 3 + (in_u,) * 3 +
        ((f"{in_u} per m s-2",) * 9 if g_sensitivity is not None else ()),
        matrix=M, bias=np.asarray(b, dtype=float), input_units=input_units, input_factor=float(input_factor),
        input_kind=input_kind, dt=float(sample_dt), output_units="rad s-1", scale_factors=sf,
        scale_factor_std=sf_std, scale_factor_units=_sf_units("gyro", input_units, in_u),
        residual_rms=float(np.sqrt(np.mean(ang ** 2))), residual_units="deg", n_residuals=int(m),
        identifiability=ident, notes=notes,
        g_sensitivity=None if g_sensitivity is None else np.asarray(g_sensitivity, dtype=float),
        extra={"pair_angles_deg": ang, "rms_before_deg": float(np.sqrt(np.mean(before ** 2))),
               "n_motions": prob.n_pairs, "nfev": int(sol.nfev), "scale_guess": scale_guess,
               "bias_estimated": bool(nb)})


def direction_check(result: "FieldCalResult", accel_raw, gyro_raw, fs: float, intervals=None, **detect_kwargs):
    """Validate a calibration by gravity directions: calibrate, find static intervals on the calibrated signals
    (or use ``intervals``), integrate the calibrated gyro over each gap and compare the carried gravity
    direction with the next one. Returns ``(angles_deg per gap, intervals)``. Only meaningful for a recording
    that is continuous between its static intervals (not for sessions pasted together from pieces).
    """
    a, w = result.apply(accel_raw, gyro_raw)
    if intervals is None:
        intervals = detect.detect_static(a, w, fs, **detect_kwargs).intervals
    iv = np.asarray(intervals, dtype=np.int64).reshape(-1, 2)
    if len(iv) < 2:
        raise FieldCalError("direction_check: fewer than two static intervals")
    prob = _GyroProblem(w, a, iv, np.full(len(w), 1.0 / fs), np.zeros(3))
    return direction_angles_deg(prob.residual_vectors(np.eye(3))), iv


# =========================================================================== Ferraris (labelled sessions)

_LABEL = re.compile(r"^([xyz])_([pa])$")


def fit_ferraris(accel, gyro, fs: float, statics: dict, turns: list, gravity: float, *,
                 accel_units="count", accel_factor=1.0, gyro_units="count", gyro_factor=1.0,
                 input_kind="rate", dt=None, path=None):
    """Ferraris calibration from labelled static positions and known turns (imucal's sessions).

    ``statics``: ``{label: sample index array}`` with imucal labels ``x_p`` (x up: accel reads +g on x),
    ``x_a`` (x down), ... -- all six. The norm model (9 parameters) is not determined by six orientations, so
    the labels are used as *vector* observations of ``N = M f + b`` with ``f = +-g`` along the labelled axis
    (12 unknowns, 18 equations), solved in Ferraris' closed form: ``M`` columns ``(N+ - N-) / 2g`` (also the
    least-squares solution), ``b_i`` the midpoint of the on-axis components of the i-axis pair (Ferraris
    eq. 20; the least-squares ``b``, the mean of all six, absorbs the tilt of hand-placed positions and is
    reported for comparison only). Scale factors = row norms of ``M`` (imucal's ``K_a``). ``turns``: ``[(axis 0..2, angle_rad, sample index
    array)]``, angles signed by the right-hand rule: gyro bias = mean over the static samples, ``M_g`` columns
    = integrated bias-free gyro / angle. Inputs in the calibration's input units. Returns (accel, gyro)
    :class:`TriadFit`.
    """
    accel = np.asarray(accel, dtype=float)
    gyro = np.asarray(gyro, dtype=float)
    need = [f"{a}_{s}" for a in "xyz" for s in "pa"]
    missing = [lab for lab in need if lab not in statics]
    if missing:
        raise FieldCalError(f"{path or 'input'}: Ferraris needs the six labelled static positions {need}; "
                            f"missing {missing} -- fix: label them (imucal convention) or use method 'norm'")
    F, Nm, n_per = [], [], []
    for lab in need:
        ax, sgn = "xyz".index(lab[0]), (1.0 if lab[2] == "p" else -1.0)
        f = np.zeros(3)
        f[ax] = sgn * gravity
        F.append(np.concatenate([f, [1.0]]))
        Nm.append(accel[statics[lab]].mean(axis=0))
        n_per.append(len(statics[lab]))
    F, Nm = np.array(F), np.array(Nm)
    up, down = Nm[0::2], Nm[1::2]  # rows: x, y, z positions
    M = (up - down).T / (2.0 * gravity)  # columns: Ferraris eq. 21-22, N+ - N- = 2 g M e_i
    b = np.diag((up + down).T / 2.0).copy()  # Ferraris eq. 20: on-axis midpoints only
    res = Nm - F[:, :3] @ M.T - b  # off-axis placement scatter (on-axis entries are zero by construction)
    dof = Nm.size - 12
    sigma2 = float(np.sum(res * res)) / dof
    cov = np.zeros((12, 12))
    for r in range(3):  # each entry of M from one difference of two means, each b_r from one sum
        cov[3 * r:3 * r + 3, 3 * r:3 * r + 3] = np.eye(3) * sigma2 / (2.0 * gravity ** 2)
        cov[9 + r, 9 + r] = sigma2 / 2.0
    C = np.linalg.inv(M)
    sf = np.linalg.norm(M, axis=1)
    sf_std = np.full(3, math.sqrt(sigma2 / (2.0 * gravity ** 2)))
    ident = identifiability(F, ("f_x", "f_y", "f_z", "1"), based_on="Ferraris design (six labelled positions)")
    # the full linear least squares (b = mean of the six) for comparison: sensitive to placement tilt
    X_ls, *_ = np.linalg.lstsq(F, Nm, rcond=None)
    b_ls = X_ls[3]
    static_idx = np.concatenate([statics[lab] for lab in need])
    cal = (accel[static_idx] - b) @ C.T
    r = np.linalg.norm(cal, axis=1) - gravity
    r_ls = np.linalg.norm((accel[static_idx] - b_ls) @ C.T, axis=1) - gravity
    in_a = _input_label("accel", accel_units, input_kind)
    dt_s = 1.0 / fs if dt is None else dt
    acc = TriadFit(
        sensor="accel", method="ferraris", names=FERRARIS_M_NAMES + BIAS_NAMES,
        values=np.concatenate([M.ravel(), b]), covariance=cov,
        param_units=(f"{in_a} per m s-2",) * 9 + (in_a,) * 3, matrix=C, bias=b, input_units=accel_units,
        input_factor=float(accel_factor), input_kind=input_kind, dt=dt_s, output_units="m s-2",
        scale_factors=sf, scale_factor_std=sf_std,
        scale_factor_units=_sf_units("accel", accel_units, in_a),
        residual_rms=float(np.sqrt(np.mean(r * r))), residual_units="m s-2", n_residuals=int(len(r)),
        identifiability=ident,
        notes=["six static positions cannot determine the nine-parameter norm model (6 norm equations, 9 "
               "unknowns); the labelled orientations are used as vector observations instead: N = M f + b with "
               "f = +-g along the labelled axis, Ferraris closed form (M columns (N+ - N-) / 2g, bias from the "
               "on-axis midpoints, which hand-placement tilt barely affects)",
               f"the full least-squares bias (mean of the six positions) would give a static-norm RMS of "
               f"{float(np.sqrt(np.mean(r_ls ** 2))):.4g} m s-2 (placement tilt leaks into it)"],
        extra={"position_residuals": res, "sigma_placement": math.sqrt(sigma2), "labels": need,
               "samples_per_position": n_per, "static_norm_rms_lsq_bias": float(np.sqrt(np.mean(r_ls ** 2)))})
    if len(turns) != 3 or sorted(t[0] for t in turns) != [0, 1, 2]:
        raise FieldCalError(f"{path or 'input'}: Ferraris gyro needs one turn about each axis x, y, z; got axes "
                            f"{[t[0] for t in turns]} -- fix: label x_rot, y_rot, z_rot")
    bg = gyro[static_idx].mean(axis=0)
    W = np.zeros((3, 3))
    angles = np.zeros(3)
    for ax, ang, idx in turns:
        W[:, ax] = (gyro[idx] - bg).sum(axis=0) * dt_s
        angles[ax] = ang
    Mg = W / angles[None, :]
    Cg = np.linalg.inv(Mg)
    turn_out = {}
    for ax, ang, idx in turns:
        integ = ((gyro[idx] - bg) @ Cg.T).sum(axis=0) * dt_s
        turn_out["xyz"[ax]] = np.degrees(integ)
    sfg = np.linalg.norm(Mg, axis=1)
    bg_std = gyro[static_idx].std(axis=0, ddof=1) / math.sqrt(len(static_idx))
    covg = np.full((12, 12), np.nan)
    covg[9:, 9:] = np.diag(bg_std ** 2)
    in_g = _input_label("gyro", gyro_units, input_kind)
    gyr = TriadFit(
        sensor="gyro", method="ferraris", names=FERRARIS_M_NAMES + BIAS_NAMES,
        values=np.concatenate([Mg.ravel(), bg]), covariance=covg,
        param_units=(f"{in_g} per rad s-1",) * 9 + (in_g,) * 3, matrix=Cg, bias=bg, input_units=gyro_units,
        input_factor=float(gyro_factor), input_kind=input_kind, dt=dt_s, output_units="rad s-1",
        scale_factors=sfg, scale_factor_std=np.full(3, np.nan),
        scale_factor_units=_sf_units("gyro", gyro_units, in_g),
        residual_rms=0.0, residual_units="deg", n_residuals=0, identifiability=None,
        notes=["three turns determine the nine entries of M_g exactly (no redundancy: no residual, no "
               "covariance); bias from the static positions; gyro g-sensitivity not modelled"],
        extra={"turn_angles_deg": turn_out, "declared_angles_deg": np.degrees(angles)})
    return acc, gyr


# =========================================================================== recording-level workflow


def _units_of(ds, var):
    units = ds[var].attrs.get("units")
    kind = ds[var].attrs.get("sample_kind", "rate")
    if units == "count":
        return units, 1.0, kind
    f = recording.unit_factor(units)
    if f is None:
        raise FieldCalError(f"{ds.attrs.get('_path', 'dataset')}: variable '{var}': units {units!r} unknown")
    return units, f, kind


def _check_settings(settings, src):
    for key in settings:
        if key.startswith("_"):
            continue
        if key not in SETTINGS_KEYS:
            raise FieldCalError(f"{src}: fieldcal settings key '{key}' unknown -- fix: one of "
                                f"{', '.join(sorted(SETTINGS_KEYS))}")
    det = settings.get("detection") or {}
    if not isinstance(det, dict):
        raise FieldCalError(f"{src}: settings 'detection' must be a mapping")
    rule = det.get("rule", "detect")
    allowed = {"detect": DETECTION_KEYS_DETECT, "imu_tk": DETECTION_KEYS_IMU_TK}.get(rule)
    if allowed is None:
        raise FieldCalError(f"{src}: settings 'detection.rule' = {rule!r} -- fix: 'detect' or 'imu_tk'")
    for key in det:
        if key not in allowed:
            raise FieldCalError(f"{src}: settings 'detection.{key}' unknown for rule {rule!r} -- fix: one of "
                                f"{', '.join(sorted(allowed))}")
    gy = settings.get("gyro") or {}
    for key in gy:
        if key not in GYRO_KEYS:
            raise FieldCalError(f"{src}: settings 'gyro.{key}' unknown -- fix: one of {', '.join(sorted(GYRO_KEYS))}")
    if gy.get("bias", "g_sensitive") not in GYRO_BIAS_MODES:
        raise FieldCalError(f"{src}: settings 'gyro.bias' = {gy.get('bias')!r} -- fix: one of "
                            f"{', '.join(GYRO_BIAS_MODES)}")
    if gy.get("dt", "nominal") not in ("nominal", "timestamps"):
        raise FieldCalError(f"{src}: settings 'gyro.dt' = {gy.get('dt')!r} -- fix: nominal or timestamps")
    for ev in settings.get("evaluate") or []:
        if ev not in EVALUATIONS:
            raise FieldCalError(f"{src}: settings 'evaluate' entry {ev!r} -- fix: one of {', '.join(EVALUATIONS)}")
    if settings.get("method", "auto") not in ("auto", "norm", "ferraris"):
        raise FieldCalError(f"{src}: settings 'method' = {settings.get('method')!r} -- fix: auto, norm or ferraris")


def _labelled(ds):
    """imucal-labelled statics {label: idx} and turns [(axis, angle_rad, idx)] from the segment table."""
    if "segment_label" not in ds or "segment_index" not in ds:
        return {}, []
    si = np.asarray(ds["segment_index"].values)
    statics, turns = {}, []
    for k, (lab, kind) in enumerate(zip(ds["segment_label"].values, ds["segment_kind"].values)):
        lab, kind = str(lab), str(kind)
        idx = np.flatnonzero(si == k)
        if kind == "static" and _LABEL.match(lab):
            statics[lab] = idx
        elif kind == "rotation" and "rotation_axis" in ds:
            axis = np.asarray(ds["rotation_axis"].values[k], dtype=float)
            ax = int(np.argmax(np.abs(axis)))
            if "rotation_angle" in ds:
                ang = float(ds["rotation_angle"].values[k])
            else:
                ang = float(ds["rotation_rate"].values[k]) * len(idx) / float(ds.attrs["sample_rate_hz"])
            turns.append((ax, math.radians(ang * np.sign(axis[ax])), idx))
    return statics, turns


def fieldcal_recording(path_or_ds, settings: dict | None = None) -> FieldCalResult:
    """Field-calibrate a ``calib-recording-1`` recording (path or in-memory dataset).

    Settings (all optional; unknown keys are an error):

    ``method``: ``auto`` (default: ``ferraris`` when the segment table holds the six imucal static labels
    and the turns, else ``norm``), ``norm`` or ``ferraris``.
    ``gravity_m_s2``: local gravity; default the recording's ``gravity_m_s2`` attribute, else WGS-84 normal
    gravity at its latitude and height.
    ``detection``: ``{rule: detect, ...}`` -- :func:`calib.signal.detect.detect_static` keyword arguments
    (``window_s, min_interval_s, threshold, k, init_s, gyro_threshold, use_gyro, ...``), or
    ``{rule: imu_tk, k: 10 or [2, ..., 10], init_samples: 5000, window: 101, samples_per_interval: 100,
    min_intervals: 12}`` -- IMU-TK's selection (:func:`imu_tk_accel_search`; a list of ``k`` = its search
    for the smallest cost).
    ``samples_per_interval``: with rule ``detect``, fit on the first n samples of each interval (None: all).
    ``min_intervals`` (9), ``recommended_intervals`` (12), ``rank_rtol`` (1e-6).
    ``gyro``: ``{enabled: true, bias: g_sensitive | initial | statics | estimate, dt: nominal | timestamps,
    scale_guess: input units per rad s-1}``. ``g_sensitive`` (default): offset ``b + G a`` with ``b`` and the
    g-sensitivity ``G`` fitted to the static gyro means against the calibrated accel means
    (:func:`gyro_static_regression`; falls back to ``statics`` when the orientations do not determine it);
    ``initial`` = mean over the initial rest (IMU-TK: its first ``init_samples + 1`` samples);
    ``estimate`` = that, refined in the direction fit; ``statics`` = mean over all static samples.
    ``evaluate``: list of extra checks: ``mikoff_standstill`` (the norm RMS over the standstill samples
    mikoff/imu-calib selects, :func:`mikoff_standstill`: ``static_norm_rms_mikoff_standstill``), ``directions``
    (:func:`direction_check` on the detected statics of the calibrated signals: ``direction_check_rms_deg``;
    continuous recordings only).
    """
    t_start = _time.perf_counter()
    settings = dict(settings or {})
    if isinstance(path_or_ds, xr.Dataset):
        ds = path_or_ds
        src = str(ds.attrs.get("_path", "<dataset>"))
    else:
        src = str(path_or_ds)
        ds = recording.load(Path(path_or_ds))
    _check_settings(settings, src)
    fs = float(ds.attrs["sample_rate_hz"])
    dt_nom = 1.0 / fs
    g = settings.get("gravity_m_s2")
    if g is None:
        g = ds.attrs.get("gravity_m_s2")
    if g is None:
        g = float(earth.normal_gravity(math.radians(float(ds.attrs["latitude_deg"])),
                                       float(ds.attrs.get("height_m", 0.0))))
        g_src = "WGS-84 normal gravity at the recording's site"
    else:
        g_src = "settings" if settings.get("gravity_m_s2") is not None else "recording attribute gravity_m_s2"
    g = float(g)
    au, af, ak = _units_of(ds, "accel")
    gu, gf, gk = _units_of(ds, "gyro")
    acc_in = np.asarray(ds["accel"].values, dtype=np.float64) * af
    gyr_in = np.asarray(ds["gyro"].values, dtype=np.float64) * gf
    if ak == "increment":
        acc_in = acc_in / dt_nom
    if gk == "increment":
        gyr_in = gyr_in / dt_nom
    acc_units_in = "count" if au == "count" else "m s-2"
    gyr_units_in = "count" if gu == "count" else "rad s-1"
    method = settings.get("method", "auto")
    statics, turns = _labelled(ds)
    if method == "auto":
        method = "ferraris" if len(statics) == 6 and len(turns) == 3 else "norm"
    gset = settings.get("gyro") or {}
    notes = [f"gravity {g:.6g} m s-2 from {g_src}"]
    metrics = {}
    sensor = str(ds.attrs.get("sensor", ""))

    if method == "ferraris":
        acc_fit, gyr_fit = fit_ferraris(acc_in, gyr_in, fs, statics, turns, g, accel_units=acc_units_in,
                                        accel_factor=af, gyro_units=gyr_units_in, gyro_factor=gf,
                                        input_kind=ak, dt=dt_nom, path=src)
        iv = np.array([[idx[0], idx[-1] + 1] for lab, idx in sorted(statics.items(), key=lambda kv: kv[1][0])])
        frame = ("frame of the labelled case axes: x, y, z are the directions held up in x_p, y_p, z_p (assumed "
                 "orthogonal, as the Ferraris method does); gyro output in the same frame")
        rule = "segment labels of the recording (imucal x_p ... z_a, x_rot ... z_rot)"
        metrics["static_norm_rms_m_s2"] = acc_fit.residual_rms
        metrics["static_position_mean_norm_rms_m_s2"] = float(np.sqrt(np.mean(
            (np.linalg.norm(((np.array([acc_in[statics[lab]].mean(axis=0) for lab in statics]) - acc_fit.bias)
                             @ acc_fit.matrix.T), axis=1) - g) ** 2)))
        metrics["turn_angles_deg"] = {k: [float(x) for x in v] for k, v in gyr_fit.extra["turn_angles_deg"].items()}
        if not gset.get("enabled", True):
            gyr_fit = None
    else:
        det_cfg = dict(settings.get("detection") or {})
        rule_name = det_cfg.pop("rule", "detect")
        common = dict(input_units=acc_units_in, input_factor=af, input_kind=ak, dt=dt_nom,
                      rank_rtol=float(settings.get("rank_rtol", 1e-6)))
        if rule_name == "imu_tk":
            cfg = {**IMU_TK_DEFAULTS, **det_cfg}
            acc_fit, k_used, iv, table = imu_tk_accel_search(
                acc_in, fs, g, k=cfg["k"], init_samples=int(cfg["init_samples"]), window=int(cfg["window"]),
                samples_per_interval=int(cfg["samples_per_interval"]), min_intervals=int(cfg["min_intervals"]),
                path=src, **common)
            rule = (f"IMU-TK: accel variance magnitude in a {cfg['window']}-sample centred window < k x that of "
                    f"samples [0, {cfg['init_samples']}]; k searched over {cfg['k']} for the smallest cost, "
                    f"k = {k_used} chosen; first {cfg['samples_per_interval']} samples of each interval")
            metrics["imu_tk_k"] = k_used
            metrics["imu_tk_search"] = [[kk, n, c, r] for kk, n, c, r in table]
            init_span = (0, int(cfg["init_samples"]) + 1)
        else:
            d = detect.detect_static(acc_in, gyr_in, fs, **det_cfg)
            iv = d.intervals
            n_per = settings.get("samples_per_interval")
            acc_fit = fit_accel_norm(acc_in, iv, g, samples_per_interval=n_per,
                                     min_intervals=int(settings.get("min_intervals", MIN_INTERVALS)),
                                     recommended_intervals=int(settings.get("recommended_intervals",
                                                                            RECOMMENDED_INTERVALS)),
                                     detection=d, path=src, **common)
            rule = d.rule + ("" if n_per is None else f"; first {n_per} samples of each interval")
            init_span = d.init_span if d.init_span is not None else tuple(iv[0])
        frame = ("accelerometer-triad frame (IMU-TK convention): body x = accel x axis, body y in the plane of the "
                 "accel x and y axes, body z completing a right-handed orthogonal frame; gyro output in the same "
                 "frame (its misalignment includes the gyro-to-accel alignment)")
        metrics["static_norm_rms_m_s2"] = acc_fit.residual_rms
        metrics["static_interval_mean_norm_rms_m_s2"] = acc_fit.extra["interval_norm_rms"]
        metrics["n_fit_samples"] = acc_fit.n_residuals
        gyr_fit = None
        if gset.get("enabled", True):
            acc_cal = acc_fit.apply(np.asarray(ds["accel"].values))
            bias_mode = gset.get("bias", "g_sensitive")
            gsens = off_cov = None
            if bias_mode == "g_sensitive":
                reg = gyro_static_regression(gyr_in, acc_cal, iv, float(settings.get("rank_rtol", 1e-6)))
                if reg["rank"] < 4:
                    bias_mode = "statics"
                    notes.append("gyro bias: static orientations too few or coplanar for the g-sensitivity "
                                 f"({reg['identifiability'].describe()}); constant bias over the statics used")
                else:
                    b0, gsens, off_cov = reg["bias"], reg["G"], reg["covariance"]
                    metrics["gyro_static_offset_rms"] = [float(v) for v in reg["rms"]]
                    metrics["gyro_static_offset_spread"] = [float(v) for v in reg["spread"]]
            if bias_mode == "statics":
                b0 = np.concatenate([gyr_in[a:b] for a, b in iv]).mean(axis=0)
            elif bias_mode in ("initial", "estimate"):
                b0 = gyr_in[init_span[0]:init_span[1]].mean(axis=0)
            if gset.get("dt", "nominal") == "timestamps":
                if "time" not in ds.coords:
                    raise FieldCalError(f"{src}: gyro.dt = timestamps but the recording has no time coordinate")
                t = np.asarray(ds["time"].values, dtype=float)
                dts = np.concatenate([np.diff(t), [dt_nom]])
            else:
                dts = np.full(len(gyr_in), dt_nom)
            gyr_fit = fit_gyro_directions(gyr_in, acc_cal, iv, dts, bias=b0, g_sensitivity=gsens,
                                          offset_covariance=off_cov, estimate_bias=(bias_mode == "estimate"),
                                          scale_guess=gset.get("scale_guess"), input_units=gyr_units_in,
                                          input_factor=gf, input_kind=gk, sample_dt=dt_nom,
                                          rank_rtol=float(settings.get("rank_rtol", 1e-6)), path=src)
            gyr_fit.notes.append({
                "g_sensitive": "offset b + G a: bias and g-sensitivity G from a least-squares fit of the static gyro "
                               "means to the calibrated accel means (independent of the direction residuals)",
                "initial": f"bias: mean of the initial rest, samples [{init_span[0]}, {init_span[1]}) (IMU-TK)",
                "estimate": f"bias: estimated, starting from the initial-rest mean [{init_span[0]}, {init_span[1]})",
                "statics": "bias: mean over all static samples"}[bias_mode])
            gyr_fit.notes.append(f"integration step: {gset.get('dt', 'nominal')}")
            metrics["gyro_direction_rms_deg"] = gyr_fit.residual_rms
            metrics["gyro_direction_rms_before_deg"] = gyr_fit.extra["rms_before_deg"]
            metrics["gyro_direction_max_deg"] = float(np.max(gyr_fit.extra["pair_angles_deg"]))
    for ev in settings.get("evaluate") or []:
        if ev == "mikoff_standstill":
            if gyr_units_in == "rad s-1":
                w_rad = gyr_in
            elif gyr_fit is not None:
                w_rad = gyr_fit.apply(ds["gyro"].values, acc_fit.apply(np.asarray(ds["accel"].values)))
            else:
                raise FieldCalError(f"{src}: evaluate mikoff_standstill needs the gyro in rad s-1 or calibrated")
            mask = mikoff_standstill(w_rad)
            metrics["static_norm_rms_mikoff_standstill"] = norm_residual_rms(
                acc_fit.apply(np.asarray(ds["accel"].values)), g, mask=mask)
            metrics["n_mikoff_standstill_samples"] = int(mask.sum())
        elif ev == "directions":
            if gyr_fit is None:
                raise FieldCalError(f"{src}: evaluate 'directions' needs the gyro calibration (gyro.enabled)")
            res_tmp = FieldCalResult(method, acc_fit, gyr_fit, "", g, np.zeros((0, 2)), "", src, sensor, {}, [], {})
            ang, ivd = direction_check(res_tmp, ds["accel"].values, ds["gyro"].values, fs)
            metrics["direction_check_rms_deg"] = float(np.sqrt(np.mean(ang ** 2)))
            metrics["direction_check_max_deg"] = float(np.max(ang))
            metrics["direction_check_n_gaps"] = int(len(ang))
    metrics["runtime_s"] = _time.perf_counter() - t_start
    return FieldCalResult(method=method, accel=acc_fit, gyro=gyr_fit, frame=frame, gravity_m_s2=g,
                          intervals=np.asarray(iv, dtype=np.int64).reshape(-1, 2), detection_rule=rule, source=src,
                          sensor=sensor, metrics=metrics, notes=notes,
                          settings={k: v for k, v in settings.items() if not k.startswith("_")})
