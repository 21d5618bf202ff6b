"""A calibration in other tools' formats: IMU-TK's text matrices, imucal's Ferraris JSON, calib's own JSON; Kalibr's
``imu.yaml`` noise file; and the reading of calib's calibration results into one form.

The one form (:class:`Calibration`): a pair of :class:`calib.core.triad.TriadModel` (``N = K E x + b``; ``x`` the
physical input in the model's input unit, ``N`` the sensor's reading in its output unit) plus, per triad, the
factor ``f`` taking the recording's *rate reading* ``r`` to ``N`` (``N = f r``) and, for the gyro, the
g-sensitivity ``G`` (``N_g = K_g E_g w + b_g + G a``, ``a`` the calibrated specific force [m s-2]). The rate
reading is the recording's sample for ``sample_kind = rate`` and sample / dt (sample x ``sample_rate_hz``) for
``increment`` samples, in the recording's units per second (``count`` -> ``count s-1``, ``deg`` -> ``deg s-1``).
Hence, in SI (specific force [m s-2], angular rate [rad s-1], body frame of the calibration)::

    a = A_a (r_a - beta_a),            A_a = s_a (K_a E_a)^-1 f_a,   beta_a = b_a / f_a
    w = A_g (r_g - beta_g - G_r a),    A_g = s_g (K_g E_g)^-1 f_g,   beta_g = b_g / f_g,   G_r = G / f_g      (1)

with ``s`` the factor of the model's input unit to SI (9.80665 for g, pi / 180 / 3600 for deg h-1, 1 for SI).
Every export writes (1) exactly, for raw rate readings ``r`` in the recording's units, and states those units:

* IMU-TK (``CalibratedTriad_::save``): per triad a text file of the misalignment matrix T (3 rows), a blank line,
  the scale matrix K (diagonal), a blank line, the bias vector B (one per line), applied as ``X' = T K (X - B)``
  (``unbiasNormalize``): T K = A, T with unit diagonal (T = A diag(A)^-1, K = diag(A)), B = beta. IMU-TK's
  estimator keeps the accelerometer T upper triangular (its "body" frame); a calibration in another frame gives
  a full T, which IMU-TK's loader and ``unbiasNormalize`` apply exactly (the export says so). IMU-TK has no
  g-sensitivity: a gyro calibration with one is refused. Files ``<prefix>_acc.calib``, ``<prefix>_gyro.calib``
  and ``<prefix>_calib.txt`` (units, conventions, provenance: IMU-TK's files hold numbers only).
* imucal (``FerrarisCalibrationInfo``, JSON format 2.0.0): ``acc = inv(R_a) inv(K_a) (acc_raw - b_a)`` in m s-2,
  ``gyr = inv(R_g) inv(K_g) (gyr_raw - K_ga acc - b_g)`` in deg s-1 (imucal's output units) with ``acc`` the
  calibrated specific force: K R = A^-1 (deg s-1 for the gyro), K diagonal holding the row norms, R with unit-norm
  rows (imucal's Ferraris convention), b = beta, K_ga = G_r.
* json (``calib-calibration-1``): the models (K, E, b with units), A, beta, G_r and the formula (1).

Full double precision everywhere (IMU-TK writes 6 significant digits by default; the files here read back to
the same corrected samples).
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import xarray as xr

from calib import __version__
from calib.core.errors import InputError
from calib.core.triad import TriadCorrection, TriadModel
from calib.io import EXPORT_FORMATS
from calib.io.atomic import output_set, write_text
from calib.io.netcdf import conventions, internal_units
from calib.io.recording import unit_factor

FORMATS = EXPORT_FORMATS
JSON_CONVENTION = "calib-calibration-1"
#: rate-reading unit of increment samples
RATE_UNIT = {"count": "count s-1", "m s-1": "m s-2", "rad": "rad s-1", "deg": "deg s-1"}
SI = {"accel": "m s-2", "gyro": "rad s-1"}
IMUCAL_FORMAT_VERSION = "2.0.0"


def rate_unit(units: str, kind: str) -> str:
    """Unit of the rate reading of samples in ``units`` of ``kind`` (rate: the same; increment: per second)."""
    return RATE_UNIT.get(units, f"{units} s-1") if kind == "increment" else units


@dataclass
class TriadCal:
    """One triad of a :class:`Calibration`: the model, the factor ``f`` from the rate reading to the model's output
    ``N = f r``, the rate reading's unit, the (units, sample_kind) of the recording channels it applies to
    (``accepts``), and the gyro's g-sensitivity ``G`` (model output unit per m s-2)."""

    sensor: str
    model: TriadModel
    factor: float
    rate_units: str
    accepts: tuple
    g_sensitivity: np.ndarray | None = None

    @property
    def si_factor(self) -> float:
        s = unit_factor(self.model.input_unit)
        if s is None:
            raise InputError(f"{self.sensor} model input unit {self.model.input_unit!r} has no SI factor")
        return s

    @property
    def correction(self) -> TriadCorrection:
        """The triad's correction of rate readings (:class:`calib.core.triad.TriadCorrection`), eq. (1)."""
        return TriadCorrection.from_model(self.model, self.sensor, output_unit=SI[self.sensor],
                                          output_factor=self.si_factor, reading_factor=self.factor,
                                          reading_unit=self.rate_units, g_sensitivity=self.g_sensitivity)

    @property
    def A(self) -> np.ndarray:
        """SI output per rate-reading unit, eq. (1)."""
        return self.correction.matrix

    @property
    def beta(self) -> np.ndarray:
        return self.correction.bias

    @property
    def G_rate(self) -> np.ndarray:
        """g-sensitivity in rate-reading units per m s-2 (zeros when none)."""
        G = self.correction.g_sensitivity
        return np.zeros((3, 3)) if G is None else G


@dataclass
class Calibration:
    """A calibration of calib (field calibration or the calibrate stage) in the one form of eq. (1)."""

    accel: TriadCal
    gyro: TriadCal | None
    kind: str
    source: str
    frame: str = ""
    notes: list = field(default_factory=list)

    def check_recording(self, sensor: str, units: str, kind: str, path="") -> None:
        """Refuse a recording channel the calibration was not made for (units and sample kind)."""
        t = self.accel if sensor == "accel" else self.gyro
        if t is None:
            return
        if (units, kind) not in t.accepts:
            ok = ", ".join(f"{u} ({k})" for u, k in t.accepts)
            raise InputError(f"'{sensor}' is {units} ({kind}) but the calibration {self.source} applies to {ok}",
                             file=path, field=sensor, fix="apply the calibration made for this unit and its output")

    def apply(self, accel_rate, gyro_rate=None):
        """Calibrated specific force [m s-2] (and angular rate [rad s-1]) of rate readings (n, 3), eq. (1)."""
        a = self.accel.correction.apply(accel_rate)
        if gyro_rate is None:
            return a
        if self.gyro is None:
            raise InputError("the calibration holds no gyro", file=self.source)
        return a, self.gyro.correction.apply(gyro_rate, accel=a)

    def how_to_apply(self) -> str:
        s = (f"accel [m s-2] = A_a (r_a - beta_a), r_a the accel rate reading in {self.accel.rate_units}")
        if self.gyro is not None:
            s += (f"; gyro [rad s-1] = A_g (r_g - beta_g - G_r a), r_g in {self.gyro.rate_units}, a the calibrated "
                  "accel [m s-2]")
        return s + " (rate reading = sample, or sample x sample_rate_hz for increment samples)"


# --------------------------------------------------------------------------- reading calib's results


def _fix(path):
    return ("give a 'calib fieldcal --out result.nc', a 'calib calibrate' default_calibration.nc or a "
            f"'calib export --format json' file (not {Path(path).name})")


def load_calibration(path) -> Calibration:
    """Read a field calibration (``calib-fieldcal-1``), a calibrate-stage ``default_calibration.nc`` or a
    ``calib-calibration-1`` JSON into a :class:`Calibration`; anything else is refused (InputError)."""
    p = Path(path)
    if not p.exists():
        raise InputError("calibration file not found", file=p)
    if p.is_dir():
        raise InputError("is a folder, not a calibration file", file=p, fix=_fix(p))
    if p.suffix.lower() == ".json":
        return _load_json(p)
    try:
        with xr.open_dataset(p, engine="netcdf4") as d:
            d = d.load()
    except Exception as exc:  # noqa: BLE001 - whatever the netCDF library raises, it is not a calibration
        raise InputError(f"not a netCDF calibration ({type(exc).__name__})", file=p, fix=_fix(p)) from None
    conv = conventions(d.attrs)
    if conv == "calib-fieldcal-1":
        return _from_fieldcal(p, d)
    if "accel" in d and d["accel"].dims == ("parameter",) and d.sizes.get("parameter") == 12:
        return _from_calibrate(p, d)
    what = "a recording" if conv == "calib-recording-1" else "not a calibration of calib"
    raise InputError(f"is {what}", file=p, fix=_fix(p))


def _from_fieldcal(p, d) -> Calibration:
    triads = {}
    for s in ("accel", "gyro"):
        if f"{s}_matrix" not in d:
            if s == "accel":
                raise InputError("field calibration without accel_matrix", file=p, field="accel_matrix", fix=_fix(p))
            continue
        M = np.asarray(d[f"{s}_matrix"].values, dtype=float)
        bias = np.asarray(d[f"{s}_bias"].values, dtype=float)
        units = internal_units(str(d.attrs[f"{s}_input_units"]))
        kind = str(d.attrs[f"{s}_input_kind"])
        factor = float(d.attrs[f"{s}_input_factor"])
        out_units = internal_units(str(d.attrs.get(f"{s}_output_units", SI[s])))
        if not (np.all(np.isfinite(M)) and np.all(np.isfinite(bias))):
            raise InputError(f"non-finite {s} calibration", file=p, field=f"{s}_matrix")
        conv_units = rate_unit(units, kind) if units == "count" else SI[s]
        model = TriadCorrection(s, M, bias, conv_units, out_units).model()   # the field calibration's form
        G = np.asarray(d[f"{s}_g_sensitivity"].values, dtype=float) if f"{s}_g_sensitivity" in d else None
        ru = rate_unit(units, kind)
        triads[s] = TriadCal(s, model, factor, ru, ((units, kind),), G)
    return Calibration(triads["accel"], triads.get("gyro"), "fieldcal", str(p), str(d.attrs.get("frame", "")))


def _from_calibrate(p, d) -> Calibration:
    if "gyro" not in d or d["gyro"].dims != ("parameter",):
        raise InputError("calibrate result without gyro(parameter)", file=p, field="gyro", fix=_fix(p))
    triads = {}
    for s, iu in (("accel", "g"), ("gyro", "deg h-1")):
        v = np.asarray(d[s].values, dtype=float)
        if v.shape != (12,) or not np.all(np.isfinite(v)):
            raise InputError(f"'{s}' needs 12 finite parameters (K, E, b)", file=p, field=s, fix=_fix(p))
        model = TriadModel.from_vector(v, iu, "count s-1")
        triads[s] = TriadCal(s, model, 1.0, "count s-1", (("count", "increment"), ("count s-1", "rate")))
    return Calibration(triads["accel"], triads["gyro"], "calibrate", str(p), str(d.attrs.get("frame", "")))


def _load_json(p) -> Calibration:
    try:
        js = json.loads(p.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"not valid JSON ({exc})", file=p, fix=_fix(p)) from None
    if not isinstance(js, dict) or js.get("format") != JSON_CONVENTION:
        raise InputError(f"not a {JSON_CONVENTION} file", file=p, fix=_fix(p))
    triads = {}
    for s in ("accel", "gyro"):
        t = js.get(s)
        if t is None:
            continue
        m = t["model"]
        model = TriadModel(np.asarray(m["K"], float), np.asarray(m["E"], float), np.asarray(m["b"], float),
                           m["input_unit"], m["output_unit"])
        G = np.asarray(t["g_sensitivity"], float) if t.get("g_sensitivity") is not None else None
        triads[s] = TriadCal(s, model, float(t["factor"]), t["rate_units"], tuple(tuple(a) for a in t["accepts"]), G)
    if "accel" not in triads:
        raise InputError("no accel calibration", file=p, field="accel", fix=_fix(p))
    return Calibration(triads["accel"], triads.get("gyro"), js.get("kind", "json"), str(p), js.get("frame", ""))


# --------------------------------------------------------------------------- writers


def _num(v) -> str:
    return repr(float(v))


def _imutk_text(T, K, B) -> str:
    rows = ["  ".join(_num(v) for v in r) for r in T]
    rows += [""] + ["  ".join(_num(v) for v in r) for r in K]
    rows += [""] + [_num(v) for v in B]
    return "\n".join(rows) + "\n\n"


def imutk_matrices(t: TriadCal):
    """IMU-TK's (T, K, B) with ``T K (X - B)`` = eq. (1): T unit diagonal, K diagonal."""
    A = t.A
    d = np.diag(A).copy()
    if np.any(d == 0):
        raise InputError(f"{t.sensor}: the calibration matrix has a zero on its diagonal (not an IMU-TK triad)")
    return A / d[None, :], np.diag(d), t.beta


def imutk_paths(out) -> dict:
    """``<prefix>_acc.calib``, ``<prefix>_gyro.calib``, ``<prefix>_calib.txt`` for ``out`` (a prefix, or an
    existing folder: prefix ``imu`` inside it; a trailing ``.calib`` is dropped)."""
    out = Path(out)
    prefix = out / "imu" if out.is_dir() else out.with_suffix("") if out.suffix == ".calib" else out
    return {"accel": Path(f"{prefix}_acc.calib"), "gyro": Path(f"{prefix}_gyro.calib"),
            "readme": Path(f"{prefix}_calib.txt")}


def write_imutk(cal: Calibration, out) -> list:
    """IMU-TK calibration files (module docstring); returns the paths written (all or none)."""
    if cal.gyro is not None and cal.gyro.g_sensitivity is not None and np.any(cal.gyro.g_sensitivity != 0):
        raise InputError("the gyro calibration has a g-sensitivity (offset G a), which IMU-TK's CalibratedTriad "
                         "cannot hold", file=cal.source, field="gyro_g_sensitivity",
                         fix="export to imucal (K_ga) or json, or calibrate with another gyro.bias mode")
    paths = imutk_paths(out)
    texts = {}
    notes = []
    for s in ("accel", "gyro"):
        t = cal.accel if s == "accel" else cal.gyro
        if t is None:
            continue
        T, K, B = imutk_matrices(t)
        texts[s] = _imutk_text(T, K, B)
        if s == "accel" and np.max(np.abs(np.tril(T, -1))) > 1e-12:
            notes.append("the accelerometer T is not upper triangular: this calibration's body frame is not "
                         "IMU-TK's accelerometer-defined frame; IMU-TK's CalibratedTriad::load and "
                         "unbiasNormalize apply the full matrix exactly as written")
    readme = [f"IMU-TK calibration exported by calib {__version__} from {cal.source} ({cal.kind})",
              "", "Each .calib file: misalignment T (3 rows), blank line, scale K (3 rows, diagonal), blank line, "
              "bias B (3 lines), as IMU-TK's CalibratedTriad_::save writes them; apply X' = T K (X - B) "
              "(CalibratedTriad_::unbiasNormalize).",
              f"accel: X = rate reading in {cal.accel.rate_units}; X' in m s-2 (specific force, body frame)"]
    if cal.gyro is not None:
        readme.append(f"gyro: X = rate reading in {cal.gyro.rate_units}; X' in rad s-1 (angular rate, body frame)")
    readme += ["rate reading = the recording's sample (sample_kind rate) or sample x sample_rate_hz (increment)",
               f"frame: {cal.frame or 'the calibration body frame'}"] + [f"note: {n}" for n in notes]
    texts["readme"] = "\n".join(readme) + "\n"
    return _write_all({paths[k]: v for k, v in texts.items()})


def imucal_dict(cal: Calibration, comment: str = "") -> dict:
    """imucal's FerrarisCalibrationInfo as its ``to_json`` writes it (format 2.0.0; module docstring)."""
    if cal.gyro is None:
        raise InputError("imucal's Ferraris calibration needs a gyro calibration", file=cal.source, field="gyro",
                         fix="calibrate with the gyro enabled, or export to imutk / json")

    def kr(A):
        Ainv = np.linalg.inv(A)
        k = np.linalg.norm(Ainv, axis=1)
        return np.diag(k), Ainv / k[:, None]

    K_a, R_a = kr(cal.accel.A)
    K_g, R_g = kr(cal.gyro.A * (180.0 / math.pi))
    return {"acc_unit": "m/s^2", "gyr_unit": "deg/s", "from_acc_unit": cal.accel.rate_units,
            "from_gyr_unit": cal.gyro.rate_units,
            "comment": comment or f"exported by calib {__version__} from {cal.source} ({cal.kind}); raw = rate "
                                  "reading (sample, or sample x sample_rate_hz for increments)",
            "K_a": K_a.tolist(), "R_a": R_a.tolist(), "b_a": cal.accel.beta.tolist(),
            "K_g": K_g.tolist(), "R_g": R_g.tolist(), "K_ga": cal.gyro.G_rate.tolist(), "b_g": cal.gyro.beta.tolist(),
            "cal_type": "Ferraris", "_format_version": IMUCAL_FORMAT_VERSION}


def calib_json(cal: Calibration) -> dict:
    """calib's own export (``calib-calibration-1``): models, eq. (1) and provenance."""
    out = {"format": JSON_CONVENTION, "calib_version": __version__, "source": cal.source, "kind": cal.kind,
           "frame": cal.frame, "how_to_apply": cal.how_to_apply(),
           "equations": "a = A_a (r_a - beta_a); w = A_g (r_g - beta_g - G_r a); A = s (K E)^-1 f, beta = b / f, "
                        "G_r = G / f; N = K E x + b the triad model, N = f r"}
    for s in ("accel", "gyro"):
        t = cal.accel if s == "accel" else cal.gyro
        if t is None:
            out[s] = None
            continue
        m = t.model
        out[s] = {"model": {"K": m.K.tolist(), "E": m.E.tolist(), "b": np.asarray(m.b).tolist(),
                            "input_unit": m.input_unit, "output_unit": m.output_unit},
                  "factor": t.factor, "rate_units": t.rate_units, "accepts": [list(a) for a in t.accepts],
                  "si_factor": t.si_factor, "A": t.A.tolist(), "beta": t.beta.tolist(),
                  "output_units": SI[s],
                  "g_sensitivity": None if t.g_sensitivity is None else np.asarray(t.g_sensitivity).tolist(),
                  "G_r": t.G_rate.tolist()}
    return out


def write_json_export(cal: Calibration, out, fmt: str) -> list:
    d = imucal_dict(cal) if fmt == "imucal" else calib_json(cal)
    if not _finite(d):
        raise InputError("the calibration holds NaN or Inf", file=cal.source, fix="re-run the calibration")
    # imucal's key _format_version starts with '_': written as is (strict_json would drop it)
    return _write_all({Path(out): json.dumps(d, indent=4, allow_nan=False) + "\n"})


def _finite(o) -> bool:
    if isinstance(o, dict):
        return all(_finite(v) for v in o.values())
    if isinstance(o, (list, tuple)):
        return all(_finite(v) for v in o)
    return not isinstance(o, float) or math.isfinite(o)


def export(cal: Calibration, fmt: str, out) -> list:
    """Write ``cal`` in ``fmt`` (:data:`FORMATS`) to ``out``; returns the paths written."""
    if fmt == "imutk":
        return write_imutk(cal, out)
    if fmt in ("imucal", "json"):
        return write_json_export(cal, out, fmt)
    raise InputError(f"unknown export format {fmt!r}", field="--format", fix=f"one of {', '.join(FORMATS)}")


def _write_all(texts: dict) -> list:
    """Write several text files so that either all appear complete or none does."""
    with output_set():
        for path, text in texts.items():
            write_text(path, text)
    return list(texts)


# --------------------------------------------------------------------------- Kalibr


def kalibr_yaml(params: dict, rostopic: str, update_rate_hz: float, source: str = "") -> str:
    """Kalibr's ``imu.yaml`` text from :func:`calib.signal.ieee952.kalibr_parameters` ``params``."""
    def line(key):
        p = params[key]
        flag = "" if p["resolved"] else "; NOT resolved by the record: upper bound written"
        return (f"{key}: {p['value']:.9g}  # [{p['unit']}] 95 % interval [{p['lo']:.4g}, {p['hi']:.4g}]{flag}")

    head = [f"# Kalibr IMU noise parameters written by calib {__version__}" + (f" from {source}" if source else ""),
            "# Continuous-time values, Kalibr's convention: noise density = the white-noise density N of IEEE Std",
            "# 952 (ADEV at tau = 1 s on the slope -1/2 line); random walk = the rate random walk K (density of the",
            "# white noise driving the bias; ADEV at tau = 3 s on the slope +1/2 line). Kalibr discretises them",
            "# with update_rate: sigma_d = noise_density * sqrt(update_rate), and a bias step of",
            "# random_walk / sqrt(update_rate) per sample.",
            "# Units: accelerometer_noise_density m/s^2/sqrt(Hz), accelerometer_random_walk m/s^3/sqrt(Hz),",
            "# gyroscope_noise_density rad/s/sqrt(Hz), gyroscope_random_walk rad/s^2/sqrt(Hz).",
            "# Each value is the RMS of the three axes' fits, with its bootstrap interval.",
            "# These come from a static record: Kalibr users usually inflate them (noise densities often x2-x10,",
            "# random walks more) to cover motion, vibration and temperature changes of the actual session.", ""]
    body = ["# Accelerometers", line("accelerometer_noise_density"), line("accelerometer_random_walk"), "",
            "# Gyroscopes", line("gyroscope_noise_density"), line("gyroscope_random_walk"), "",
            f"rostopic: {rostopic}  # the IMU topic",
            f"update_rate: {float(update_rate_hz):.9g}  # [Hz] rate of the record (for the discretisation above)"]
    return "\n".join(head + body) + "\n"
