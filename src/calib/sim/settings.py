"""The simulator's configuration: defaults, and the checks that turn a config section into the simulator's
parameters. Every refusal is a :class:`SimConfigError` whose message names the key and the fix.

Default noise of the simulated unit (navigation-grade quartz accelerometers and FOGs; all in ``cfg['noise']``):

=================================  ===========  ==========================================================
key                                default      meaning
=================================  ===========  ==========================================================
accel_vrw_ug_rthz                  10.0         accel white noise PSD^(1/2) [ug/sqrt(Hz)] (VRW)
accel_bias_instability_ug          5.0          accel bias instability: stationary sigma of beta [ug]
accel_bias_corr_time_s             300.0        its correlation time [s] (Gauss-Markov)
gyro_arw_deg_rth                   0.002        gyro angle random walk [deg/sqrt(h)]
gyro_bias_instability_deg_h        0.003        gyro bias instability: stationary sigma of beta [deg/h]
gyro_bias_corr_time_s              600.0        its correlation time [s]
bias_model                         gauss_markov gauss_markov (stationary, starts in its stationary law) |
                                                random_walk (starts at 0; sigma reached after corr_time_s)
quantize                           true         pulse-counter int32 counts; false: float64 counts
=================================  ===========  ==========================================================

The Allan-deviation maximum of a Gauss-Markov bias of sigma s and correlation time T is about 0.62 s at
an averaging time of about 1.9 T; the "bias instability" keys set s directly (the simple reading).
"""
from __future__ import annotations

import copy
import math
from typing import NamedTuple

import numpy as np

from calib.core import earth
from calib.core.earth import STANDARD_GRAVITY
from calib.core.rotations import euler_to_dcm
from calib.core.triad import OFFDIAG, TriadModel, liu2021_model
from calib.sim import effects

NOISE_DEFAULTS = {
    "accel_vrw_ug_rthz": 10.0,
    "accel_bias_instability_ug": 5.0,
    "accel_bias_corr_time_s": 300.0,
    "gyro_arw_deg_rth": 0.002,
    "gyro_bias_instability_deg_h": 0.003,
    "gyro_bias_corr_time_s": 600.0,
    "bias_model": "gauss_markov",
    "quantize": True,
}
#: temperature channel of the unit (always recorded): T(t) = end + (start - end) exp(-t / tau)
TEMPERATURE_DEFAULTS = {"start_degC": 22.0, "end_degC": 30.0, "tau_s": 1800.0}

CALIBRATION_DEFAULTS = {
    "sample_rate_hz": 100.0,
    "dwell_s": 60.0,
    "step_deg": 45.0,
    "positions_per_phase": 8,
    "rotation_rates_deg_s": [10.0, 20.0, 30.0],
    "revolutions": 2,
    "rotation_axes": "vertical",
    "transition_s": [2.0, 3.0],
    "move_rate_deg_s": 20.0,
    "sensor": "liu2021",
    "noise": {},
    "effects": {},
    "conceal": False,
    "temperature": {},
    "site": None,
}


def _static_defaults(mode: str) -> dict:
    """The keys of both static modes; ``mode`` is the mode whose defaults these are."""
    return {"site": None, "mode": mode, "duration_h": 240.0, "sample_rate_hz": 100.0,
            "attitude_deg": {"pitch": 0.0, "roll": 0.0, "yaw": 0.0}}


STATIC_PHYSICAL_DEFAULTS = {
    **_static_defaults("physical"),
    "gyro_drift_deg_h": [-0.01, 0.01, 0.01],
    "gyro_noise": {"model": "arw", "arw_deg_rth": 0.001, "white_deg_h": 0.001},
    "accel_bias_m_s2": [0.001, 0.001, 0.001],
    "accel_vrw_ug_rthz": 0.0,
}
STATIC_COUNTS_DEFAULTS = {
    **_static_defaults("counts"),
    "sensor": "liu2021",
    "noise": {},
    "effects": {},
    "conceal": False,
    "temperature": {},
}


class SimConfigError(ValueError):
    """Bad simulator configuration; the message names the key and the fix."""


class UnitSettings(NamedTuple):
    """The simulated unit shared by the calibration and the static sessions, each part checked."""

    accel: TriadModel
    gyro: TriadModel
    noise: dict          # NOISE_DEFAULTS merged with the config, numbers as float
    effects: dict        # resolved effects (calib.sim.effects.resolve)
    temperature: dict    # TEMPERATURE_DEFAULTS merged with the config


class StaticLayout(NamedTuple):
    """Site, rate, duration, sample count and attitude of a static session."""

    latitude_deg: float
    height_m: float
    sample_rate_hz: float
    duration_h: float
    n_samples: int
    cbn: np.ndarray      # body-to-ENU direction cosine matrix C_b^n
    attitude_deg: dict   # {pitch, roll, yaw} [deg]


class PhysicalNoise(NamedTuple):
    """The noise of a physical-mode static session: its settings and per-sample sigmas."""

    gyro_noise: dict         # {model, arw_deg_rth, white_deg_h}
    accel_vrw_ug_rthz: float
    sigma_gyro_rad: float    # per sample
    sigma_accel_m_s: float   # per sample


def merge(cfg: dict, defaults: dict, where: str) -> dict:
    """``defaults`` updated by ``cfg`` (deep copies); a key of ``cfg`` not in ``defaults`` is refused."""
    cfg = dict(cfg or {})
    unknown = sorted(set(cfg) - set(defaults))
    if unknown:
        raise SimConfigError(f"{where}: unknown key(s) {', '.join(unknown)}; allowed: {', '.join(sorted(defaults))}")
    out = copy.deepcopy(defaults)
    out.update(copy.deepcopy(cfg))
    return out


def site(cfg: dict, where: str) -> tuple[float, float]:
    """``(latitude [deg], height [m])`` of ``cfg['site']``."""
    s = cfg.get("site")
    if not isinstance(s, dict) or "latitude_deg" not in s:
        raise SimConfigError(f"{where}.site.latitude_deg: required (site latitude in degrees); "
                             "pass cfg['site'] = {'latitude_deg': ..., 'height_m': ...}")
    extra = set(s) - {"latitude_deg", "height_m", "longitude_deg"}
    if extra:
        raise SimConfigError(f"{where}.site: unknown key(s) {', '.join(sorted(extra))}")
    lat = float(s["latitude_deg"])
    if not -90.0 < lat < 90.0:
        raise SimConfigError(f"{where}.site.latitude_deg: {lat} outside (-90, 90) degrees")
    return lat, float(s.get("height_m", 0.0))


def simulated_site(latitude_deg: float, height_m: float, resolved_effects: dict) -> effects.SiteTruth:
    """The world the simulator integrates: normal gravity at the recorded site, then the truth effects."""
    gamma = float(earth.normal_gravity(math.radians(latitude_deg), height_m))
    return effects.apply_truth(effects.SiteTruth(latitude_deg, height_m, gamma), resolved_effects)


def sample_rate(cfg: dict, where: str) -> float:
    """``cfg['sample_rate_hz']`` [Hz], refused unless finite and positive."""
    fs = float(cfg["sample_rate_hz"])
    if not (math.isfinite(fs) and fs > 0):
        raise SimConfigError(f"{where}.sample_rate_hz: {fs} is not a positive rate")
    return fs


def vector(v, name, shape=(3,)) -> np.ndarray:
    """``v`` as a finite float array of ``shape``."""
    a = np.asarray(v, dtype=float)
    if a.shape != shape or not np.all(np.isfinite(a)):
        raise SimConfigError(f"{name}: expected finite numbers of shape {shape}, got {v!r}")
    return a


def sensor_models(sensor_cfg="liu2021", where: str = "sensor") -> tuple[TriadModel, TriadModel]:
    """True accelerometer and gyro models.

    ``'liu2021'`` (Liu 2021 Tables 1 and 3 "separate calibration results") or a mapping
    ``{accel: {...}, gyro: {...}}`` overriding parts of it: ``K`` (3,) [count s-1 per input unit], ``b`` (3,)
    [count s-1], ``E`` (3x3 with unit diagonal, or the 6 off-diagonal terms in the order
    Exy Exz Eyx Eyz Ezx Ezy), or ``vector`` (the 12 parameters in :data:`calib.core.triad.PARAM_NAMES` order).
    Input units: accel g (9.80665 m/s^2), gyro deg/h.
    """
    acc, gyr = liu2021_model("accel"), liu2021_model("gyro")
    if sensor_cfg in (None, "liu2021"):
        return acc, gyr
    if not isinstance(sensor_cfg, dict):
        raise SimConfigError(f"{where}: expected 'liu2021' or a mapping with accel/gyro overrides, got {sensor_cfg!r}")
    extra = set(sensor_cfg) - {"accel", "gyro"}
    if extra:
        raise SimConfigError(f"{where}: unknown key(s) {', '.join(sorted(extra))}; allowed: accel, gyro")
    out = []
    for name, m in (("accel", acc), ("gyro", gyr)):
        o = sensor_cfg.get(name) or {}
        bad = set(o) - {"K", "E", "b", "vector"}
        if bad:
            raise SimConfigError(f"{where}.{name}: unknown key(s) {', '.join(sorted(bad))}; allowed: K, E, b, vector")
        if "vector" in o:
            m = TriadModel.from_vector(vector(o["vector"], f"{where}.{name}.vector", (12,)), m.input_unit,
                                       m.output_unit)
        if "K" in o:
            m.K = vector(o["K"], f"{where}.{name}.K")
            if np.any(m.K == 0):
                raise SimConfigError(f"{where}.{name}.K: scale factors must be non-zero")
        if "b" in o:
            m.b = vector(o["b"], f"{where}.{name}.b")
        if "E" in o:
            e = np.asarray(o["E"], dtype=float)
            if e.shape == (6,):
                full = np.eye(3)
                for k, (i, j) in enumerate(OFFDIAG):
                    full[i, j] = e[k]
                e = full
            e = vector(e, f"{where}.{name}.E", (3, 3))
            if not np.allclose(np.diag(e), 1.0):
                raise SimConfigError(f"{where}.{name}.E: diagonal must be 1 (Liu 2021 eq. 2), got {np.diag(e)}")
            m.E = e
        if abs(np.linalg.det(m.KE)) < 1e-12 * np.prod(np.abs(m.K)):
            raise SimConfigError(f"{where}.{name}: K E is singular")
        out.append(m)
    return out[0], out[1]


def noise_settings(noise: dict | None, where: str) -> dict:
    """:data:`NOISE_DEFAULTS` merged with ``noise``, each value checked (numbers as float)."""
    n = merge(noise or {}, NOISE_DEFAULTS, f"{where}.noise")
    for k, v in n.items():
        if k == "bias_model":
            if v not in ("gauss_markov", "random_walk"):
                raise SimConfigError(f"{where}.noise.bias_model: {v!r}; use gauss_markov or random_walk")
        elif k == "quantize":
            if not isinstance(v, bool):
                raise SimConfigError(f"{where}.noise.quantize: expected true/false, got {v!r}")
        else:
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise SimConfigError(f"{where}.noise.{k}: expected a number >= 0, got {v!r}")
            if k.endswith("corr_time_s") and v <= 0:
                raise SimConfigError(f"{where}.noise.{k}: correlation time must be positive")
            n[k] = float(v)
    return n


def temperature_settings(t: dict | None, where: str) -> dict:
    """:data:`TEMPERATURE_DEFAULTS` merged with ``t``, as floats, with a positive time constant."""
    t = merge(t or {}, TEMPERATURE_DEFAULTS, f"{where}.temperature")
    for k in t:
        t[k] = float(t[k])
    if t["tau_s"] <= 0:
        raise SimConfigError(f"{where}.temperature.tau_s: must be positive")
    return t


def unit_settings(c: dict, where: str) -> UnitSettings:
    """The simulated unit's settings shared by the calibration and the static sessions: sensor models, noise,
    effects, conceal flag and temperature profile, each checked (errors name the key)."""
    acc, gyr = sensor_models(c["sensor"], f"{where}.sensor")
    noise = noise_settings(c["noise"], where)
    try:
        eff = effects.resolve(c["effects"], f"{where}.effects")
    except effects.EffectConfigError as exc:
        raise SimConfigError(str(exc)) from exc
    if not isinstance(c["conceal"], bool):
        raise SimConfigError(f"{where}.conceal: expected true/false")
    return UnitSettings(acc, gyr, noise, eff, temperature_settings(c["temperature"], where))


def attitude(c: dict, where: str) -> tuple[np.ndarray, dict]:
    """``(C_b^n, {pitch, roll, yaw} [deg])`` of ``c['attitude_deg']`` (ENU convention of
    :mod:`calib.core.rotations`)."""
    att = c["attitude_deg"]
    if not isinstance(att, dict) or set(att) - {"pitch", "roll", "yaw"}:
        raise SimConfigError(f"{where}.attitude_deg: expected {{pitch, roll, yaw}} in degrees, got {att!r}")
    a = {k: float(att.get(k, 0.0)) for k in ("pitch", "roll", "yaw")}
    return euler_to_dcm(math.radians(a["pitch"]), math.radians(a["roll"]), math.radians(a["yaw"])), a


def static_layout(c: dict, where: str = "static_session") -> StaticLayout:
    """Site, rate, duration, sample count and attitude of a merged static-session config, each checked (one
    line naming the key on a bad value)."""
    lat, h = site(c, where)
    fs = sample_rate(c, where)
    dur_h = float(c["duration_h"])
    if not (dur_h > 0 and math.isfinite(dur_h)):
        raise SimConfigError(f"{where}.duration_h: {dur_h} is not a positive duration")
    n = int(round(dur_h * 3600.0 * fs))
    if n < 2:
        raise SimConfigError(f"{where}.duration_h: {dur_h} h at {fs} Hz gives fewer than 2 samples")
    cbn, att = attitude(c, where)
    return StaticLayout(lat, h, fs, dur_h, n, cbn, att)


def physical_noise(c: dict, dt: float, where: str = "static_session") -> PhysicalNoise:
    """The noise of a merged physical-mode static config at sample interval ``dt`` [s]: gyro ``model: arw``
    (per-sample sigma ``arw/60 sqrt(dt)`` deg) or ``white`` (sigma ``white dt``), accelerometer VRW."""
    gn = merge(c["gyro_noise"], STATIC_PHYSICAL_DEFAULTS["gyro_noise"], f"{where}.gyro_noise")
    if gn["model"] not in ("arw", "white"):
        raise SimConfigError(f"{where}.gyro_noise.model: {gn['model']!r}; use arw or white")
    for k in ("arw_deg_rth", "white_deg_h"):
        if not (float(gn[k]) >= 0):
            raise SimConfigError(f"{where}.gyro_noise.{k}: must be >= 0")
    vrw = float(c["accel_vrw_ug_rthz"])
    if not vrw >= 0:
        raise SimConfigError(f"{where}.accel_vrw_ug_rthz: must be >= 0")
    if gn["model"] == "arw":
        sig_g = float(gn["arw_deg_rth"]) * earth.DEG / 60.0 * math.sqrt(dt)  # rad per sample
    else:
        sig_g = float(gn["white_deg_h"]) * earth.DEG_PER_H * dt
    sig_a = vrw * 1e-6 * STANDARD_GRAVITY * math.sqrt(dt)  # m/s per sample
    return PhysicalNoise(gn, vrw, sig_g, sig_a)
