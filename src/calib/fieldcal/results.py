"""Result objects of the field calibration: one triad's fit (:class:`TriadFit`), the session's result
(:class:`FieldCalResult`), the settings keys and names. The identifiability of each fit is a
:class:`calib.calibration.identifiability.RankSummary`."""
from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass, field

import numpy as np
import xarray as xr

from calib.core.triad import TriadCorrection, TriadModel
from calib.calibration.identifiability import RankSummary, column_scaled, rank_summary, singular_spectrum

#: messages for the console (and a rule's log): what the poses do not determine, refusals turned into warnings
log = logging.getLogger("calib.fieldcal")


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
                 "recommended_intervals", "gyro", "evaluate", "rank_rtol", "units_check", "hold_undetermined",
                 "protocol"}
#: the session's protocol timing (settings ``protocol:``, or recording attributes ``protocol_<key>``): what the
#: detection chosen without settings uses when it is known
PROTOCOL_KEYS = ("initial_rest_s", "min_wait_s", "n_poses")
DETECTION_KEYS_DETECT = {"rule", "window_s", "min_interval_s", "threshold", "k", "init_s", "gyro_threshold",
                         "use_gyro", "onset_factor", "floor_percentile"}
DETECTION_KEYS_IMU_TK = {"rule", "k", "init_samples", "window", "samples_per_interval", "min_intervals"}
GYRO_KEYS = {"enabled", "bias", "dt", "scale_guess"}
GYRO_BIAS_MODES = ("g_sensitive", "initial", "statics", "estimate")
EVALUATIONS = ("mikoff_standstill", "directions")


class FieldCalError(ValueError):
    """Field calibration cannot proceed; the message names the input, the problem and the fix."""


# =========================================================================== what the poses determine

#: plausibility scales of the parameters: a marginal standard error above one is "not determined", above
#: WEAK_FRACTION of one "weakly determined"
PLAUSIBLE_MISALIGNMENT_RAD = math.radians(1.0)
PLAUSIBLE_SCALE_REL = 0.01
PLAUSIBLE_ACCEL_BIAS_G = 0.1
PLAUSIBLE_GYRO_BIAS_RAD_S = math.radians(10.0)
WEAK_FRACTION = 0.1
VERDICTS = ("determined", "weakly determined", "not determined")


def marginal_standard_errors(jac, sigma: float) -> np.ndarray:
    """Marginal standard errors ``sigma sqrt(diag((J^T J)^-1))`` from the identifiability SVD of the column-scaled
    Jacobian (:func:`calib.calibration.identifiability.singular_spectrum`), without a pseudo-inverse's cut-off: a
    direction the observations do not see (singular value zero, or below 1e-13 of the largest) gives an
    infinite standard error to every parameter it involves."""
    J = np.asarray(jac, dtype=float)
    c = np.linalg.norm(J, axis=0)
    c = np.where(c > 0, c, 1.0)
    S, Vt = singular_spectrum(column_scaled(J))
    smax = S[0] if S.size and S[0] > 0 else 0.0
    inv2 = np.where(S > 1e-13 * smax, 1.0 / np.where(S > 0, S, 1.0) ** 2, np.inf)
    V2 = Vt.T ** 2  # (p, k): V_jk^2
    with np.errstate(invalid="ignore"):
        terms = np.where(V2 > 1e-24, V2 * inv2[None, :], 0.0)
    se = float(sigma) * np.sqrt(terms.sum(axis=1)) / c
    return np.where(np.linalg.norm(J, axis=0) > 0, se, np.inf)


@dataclass
class Determination:
    """Which parameters a pose set determines: per parameter its marginal standard error ``se`` and plausibility
    ``scale`` (same units), the verdict (:data:`VERDICTS`), the condition number of the column-scaled Jacobian
    and the parameters ``held`` at nominal in the refit (with ``nominal`` values)."""

    names: tuple
    se: np.ndarray
    scale: np.ndarray
    verdicts: list
    condition: float
    based_on: str
    held: tuple = ()
    nominal: dict = field(default_factory=dict)

    @classmethod
    def from_jacobian(cls, jac, sigma, names, scale, based_on=""):
        """Verdicts from the Jacobian ``jac`` at the solution and the residual scale ``sigma``. The parameter whose
        marginal standard error is the largest multiple (> 1) of its plausibility scale is ``not determined`` and
        left out, the others' standard errors recomputed without it, until every remaining one is within its
        scale (a null direction is then named by the parameters it involves most, relative to their scales)."""
        J = np.asarray(jac, dtype=float)
        scale = np.asarray(scale, dtype=float)
        p = J.shape[1]
        keep = np.ones(p, dtype=bool)
        se = np.full(p, np.inf)
        while keep.any():
            se_k = marginal_standard_errors(J[:, keep], sigma)
            se[keep] = se_k
            ratio = se_k / scale[keep]
            worst = int(np.argmax(ratio))
            if not ratio[worst] > 1.0:
                break
            keep[np.flatnonzero(keep)[worst]] = False
        verdicts = [VERDICTS[2] if not k else VERDICTS[1] if e > WEAK_FRACTION * s else VERDICTS[0]
                    for k, e, s in zip(keep, se, scale)]
        cond = rank_summary(J, names, based_on=based_on).condition
        return cls(tuple(names), se, scale, verdicts, float(cond), based_on)

    @property
    def not_determined(self) -> list:
        return [n for n, v in zip(self.names, self.verdicts) if v == VERDICTS[2]]

    @property
    def weak(self) -> list:
        return [n for n, v in zip(self.names, self.verdicts) if v == VERDICTS[1]]

    def verdict(self, name: str) -> str:
        return self.verdicts[self.names.index(name)]

    def describe(self, sensor: str) -> str:
        out = f"{sensor}: condition number of the pose set {self.condition:.3g}"
        if self.not_determined:
            out += "; not determined: " + ", ".join(self.not_determined)
        if self.held:
            out += "; held at nominal (" + ", ".join(f"{k} = {v:.6g}" for k, v in self.nominal.items()) + \
                   ") and the others refitted"
        if self.weak:
            out += "; weakly determined: " + ", ".join(self.weak)
        if not self.not_determined and not self.weak:
            out += "; every parameter determined"
        return out

    def as_dict(self) -> dict:
        return {"condition": self.condition, "based_on": self.based_on, "held_at_nominal": list(self.held),
                "nominal": {k: float(v) for k, v in self.nominal.items()},
                "parameters": {n: {"se": (float(e) if math.isfinite(e) else None), "plausible_scale": float(s),
                                   "verdict": v}
                               for n, e, s, v in zip(self.names, self.se, self.scale, self.verdicts)}}


# =========================================================================== result objects


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
    identifiability: RankSummary | None
    notes: list = field(default_factory=list)
    extra: dict = field(default_factory=dict)
    g_sensitivity: np.ndarray | None = None
    determination: Determination | None = None

    @property
    def std(self) -> np.ndarray:
        """Standard errors of ``values`` (NaN where unknown)."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    def param(self, name: str) -> float:
        return float(self.values[self.names.index(name)])

    def correction(self) -> TriadCorrection:
        """This calibration as the one correction of a triad (:class:`calib.core.triad.TriadCorrection`):
        ``out = matrix (input_factor raw [/ dt] - bias [- g_sensitivity a])``."""
        conv = input_label(self.sensor, self.input_units, self.input_kind)
        return TriadCorrection(self.sensor, self.matrix, self.bias, conv, self.output_units,
                               factor=self.input_factor, g_sensitivity=self.g_sensitivity)

    def model(self) -> TriadModel:
        """This calibration as the triad model N = K E x + b of :mod:`calib.core.triad` (the one representation
        of a triad's parameters): x in ``output_units``, N in the converted input units; K E = matrix^-1."""
        return self.correction().model()

    def convert_input(self, raw) -> np.ndarray:
        """Raw samples (recording units) to the calibration's input units (counts, or SI rates)."""
        return self.correction().reading(raw, self.input_kind, self.dt)

    def apply(self, raw, accel_calibrated=None) -> np.ndarray:
        """Calibrated output (``output_units``, body frame) of raw (n, 3) samples in the recording's units.

        A g-sensitive gyro (``g_sensitivity`` set) also needs the calibrated specific force [m s-2] of the
        same samples: ``out = matrix @ (N - bias - G a)``.
        """
        if self.g_sensitivity is not None and accel_calibrated is None:
            raise FieldCalError(f"{self.sensor} calibration is g-sensitive: pass accel_calibrated (m s-2)")
        return self.correction().apply(raw, sample_kind=self.input_kind, dt=self.dt, accel=accel_calibrated)


@dataclass
class FieldCalResult:
    """Field calibration of one recording. See the module docstring for frames, models and units.

    ``apply(accel_raw, gyro_raw)`` gives calibrated specific force [m s-2] and rate [rad s-1] in the body
    frame stated by ``frame``. ``metrics``: the key numbers (also in :meth:`summary`). ``detection_choice``: when
    the settings gave no detection, how it was chosen (:mod:`calib.fieldcal.default_detection`): ``status``
    (``passed``, or ``failed`` when no candidate's result passed the result checks and this one is returned for
    inspection), ``line`` (the choice in one line), ``chosen`` and ``runner_up`` (their ``detection:`` settings,
    interval and pose counts, residual), ``protocol`` (the timing used and where it came from, when known) and
    ``candidates`` (every candidate tried, its residual or why it was not eligible; left out of :meth:`summary`);
    None when the settings gave the detection.
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
    units_check: dict | None = None
    detection_choice: dict | None = None

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
        if self.units_check is not None:
            out["units_check"] = self.units_check
        if self.detection_choice is not None:   # every candidate: detection_choice['candidates'], the netCDF attrs
            out["detection_choice"] = {k: v for k, v in self.detection_choice.items() if k != "candidates"}
        for f in (self.accel, self.gyro):
            if f is not None and f.determination is not None:
                out[f"{f.sensor}_determination"] = f.determination.as_dict()
        for f in (self.accel, self.gyro):   # Cramér–Rao bounds (calib.fieldcal.bound), norm method
            if f is not None and "sigma_crb" in f.extra:
                out[f"{f.sensor}_sigma_crb"] = f.extra["sigma_crb"]
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
            if f.determination is not None:
                attrs[f"{s}_determination"] = f.determination.describe(s)
        if self.units_check is not None:
            uc = self.units_check
            attrs["units_check"] = uc["status"] + (f": {uc['reason']}" if uc.get("reason") else "")
            attrs["units_check_closure_deg"] = np.asarray(uc.get("closure_deg") or [], dtype=float)
        if self.detection_choice is not None:
            attrs["detection_choice"] = self.detection_choice["line"]
            attrs["detection_choice_status"] = self.detection_choice.get("status", "passed")
            attrs["detection_choice_candidates"] = json.dumps(self.detection_choice["candidates"])
        for k, v in self.metrics.items():
            if isinstance(v, (int, float, str, np.integer, np.floating)) and not isinstance(v, bool):
                attrs[f"metric_{k}"] = v
        return xr.Dataset(data, coords=coords, attrs=attrs)


def _converted_units(f: TriadFit) -> str:
    if f.input_units == "count":
        return "count" if f.input_kind == "rate" else "count s-1"
    return "m s-2" if f.sensor == "accel" else "rad s-1"



def scale_factor_units(sensor, units, in_label):
    out = "m s-2" if sensor == "accel" else "rad s-1"
    return f"{in_label} per {out}" if units == "count" else f"1 (input in {out} per {out})"


def input_label(sensor, units, kind):
    if units == "count":
        return "count" if kind == "rate" else "count s-1"
    return "m s-2" if sensor == "accel" else "rad s-1"
