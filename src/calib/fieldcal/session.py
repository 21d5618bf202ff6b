"""Field calibration of a whole recording (:func:`fieldcal_recording`): settings, interval detection, the
accelerometer and gyroscope fits in order, evaluations."""
from __future__ import annotations

import math
import time as _time
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import xarray as xr

from calib.core import clock
from calib.signal import detect, plausibility
from calib.core import earth
from calib.core.errors import ResultCheckError
from calib.io import recording
from calib.fieldcal.accelerometer import fit_accel_norm, norm_residual_rms
from calib.fieldcal.ferraris import LABEL_PATTERN, fit_ferraris
from calib.fieldcal.gyroscope import direction_check, fit_gyro_directions, gyro_static_regression
from calib.fieldcal.intervals import imu_tk_accel_search, mikoff_standstill
from calib.fieldcal.units_check import UnitsCheck, UnitsCheckError, check_gyro_units
from calib.fieldcal import bound as fieldcal_bound
from calib.fieldcal import default_detection
from calib.fieldcal.results import (
    DETECTION_KEYS_DETECT,
    DETECTION_KEYS_IMU_TK,
    EVALUATIONS,
    FieldCalError,
    FieldCalResult,
    GYRO_BIAS_MODES,
    GYRO_KEYS,
    IMU_TK_DEFAULTS,
    MIN_INTERVALS,
    RECOMMENDED_INTERVALS,
    SETTINGS_KEYS,
    log,
)

# =========================================================================== recording-level workflow


#: what an accelerometer-only record's field calibration says of the gyro part (a note of the result, logged)
NO_GYRO_NOTE = ("accelerometer only: the recording holds no gyroscope (absent_sensors), so the accelerometer is "
                "calibrated from its static poses and the gyro calibration and the rotation check of the gyro's "
                "units are skipped")


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
    default_detection.protocol_section(settings, src)
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
    for key in ("units_check", "hold_undetermined"):
        if not isinstance(settings.get(key, True), bool):
            raise FieldCalError(f"{src}: settings '{key}' = {settings.get(key)!r} -- fix: true or false")
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
        if kind == "static" and LABEL_PATTERN.match(lab):
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


def clock_steps(ds, src="dataset"):
    """Clock periods from each sample to the next (n - 1,) of the recording's time coordinate
    (:func:`calib.core.clock.fit_clock`: 1, or k over k - 1 dropped samples), or None when every step is one
    period (or there is no time coordinate)."""
    if "time" not in ds.coords:
        return None
    try:
        clk = clock.fit_clock(np.asarray(ds["time"].values, dtype=float))
    except clock.ClockError as exc:
        raise FieldCalError(f"{src}: time coordinate: {exc}") from None
    return None if clk.uniform else clk.steps().astype(float)


def _units_check(settings, gyr_in, gyr_units_in, accel_dirs, iv, dts, fs, ds, src, force, notes):
    """The rotation check of the gyro's units and the rate (:mod:`calib.fieldcal.units_check`), as a dict."""
    if gyr_in is None:
        return UnitsCheck("not checked", "the recording holds no gyroscope (absent_sensors)").as_dict()
    if not settings.get("units_check", True):
        return UnitsCheck("disabled", "settings units_check: false").as_dict()
    if not (settings.get("gyro") or {}).get("enabled", True):
        return UnitsCheck("not checked", "gyro.enabled: false").as_dict()
    if gyr_units_in != "rad s-1":
        return UnitsCheck("not checked", "gyro in counts: no nominal scale to check").as_dict()
    if accel_dirs is None:
        return UnitsCheck("not checked", "accel in counts and not yet calibrated").as_dict()
    uc = check_gyro_units(gyr_in, accel_dirs, iv, dts, source=src, fs=fs,
                          rate_from_clock="clock_rate_hz" in ds.attrs, force=force)
    if uc.status == "forced":
        msg = f"units check refused ({uc.field}), overridden by force: {uc.reason}"
        notes.append(msg)
        log.warning("%s: %s", src, msg)
    elif uc.status == "not checked":
        notes.append(f"units check: not checked: {uc.reason}")
    return uc.as_dict()


@dataclass
class _Inputs:
    """A recording converted to the calibration's input units, with what every step of the norm method needs."""

    ds: xr.Dataset
    src: str
    settings: dict
    force: bool
    fs: float
    dt_nom: float
    g: float
    acc_in: np.ndarray
    gyr_in: np.ndarray
    af: float
    ak: str
    gf: float
    gk: str
    acc_units_in: str
    gyr_units_in: str
    dts_clock: np.ndarray


def _norm(inp: _Inputs, det_cfg: dict, notes: list, metrics: dict, x0=None):
    """The norm method with the detection ``det_cfg`` (a settings ``detection:`` section): intervals, accel fit,
    units check, gyro fit. Returns ``(acc_fit, gyr_fit, intervals, rule, units_check)``; ``notes`` and ``metrics``
    are filled in. ``x0``: the accel fit's start (default: the ellipsoid fit to the interval means)."""
    ds, src, settings, force, fs, dt_nom, g = inp.ds, inp.src, inp.settings, inp.force, inp.fs, inp.dt_nom, inp.g
    acc_in, gyr_in, af, ak, gf, gk = inp.acc_in, inp.gyr_in, inp.af, inp.ak, inp.gf, inp.gk
    acc_units_in, gyr_units_in, dts_clock = inp.acc_units_in, inp.gyr_units_in, inp.dts_clock
    gset = settings.get("gyro") or {}
    units_check = None
    det_cfg = dict(det_cfg)
    rule_name = det_cfg.pop("rule", "detect")
    common = dict(input_units=acc_units_in, input_factor=af, input_kind=ak, dt=dt_nom,
                  rank_rtol=float(settings.get("rank_rtol", 1e-6)))
    common["hold_undetermined"] = bool(settings.get("hold_undetermined", True))
    if x0 is not None:
        common["x0"] = x0
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
        if gyr_in is None:   # an accelerometer-only record: the accel criterion alone
            det_cfg["use_gyro"] = False
        d = detect.detect_static(acc_in, gyr_in, fs, **det_cfg)
        iv = d.intervals
        if acc_units_in != "count":
            units_check = _units_check(settings, gyr_in, gyr_units_in, acc_in, iv, dts_clock, fs, ds, src,
                                       force, notes)
        n_per = settings.get("samples_per_interval")
        acc_fit = fit_accel_norm(acc_in, iv, g, samples_per_interval=n_per,
                                 min_intervals=int(settings.get("min_intervals", MIN_INTERVALS)),
                                 recommended_intervals=int(settings.get("recommended_intervals",
                                                                        RECOMMENDED_INTERVALS)),
                                 detection=d, path=src, **common)
        rule = d.rule + ("" if n_per is None else f"; first {n_per} samples of each interval")
        init_span = d.init_span if d.init_span is not None else tuple(iv[0])
    metrics["static_norm_rms_m_s2"] = acc_fit.residual_rms
    metrics["static_interval_mean_norm_rms_m_s2"] = acc_fit.extra["interval_norm_rms"]
    metrics["n_fit_samples"] = acc_fit.n_residuals
    gyr_fit = None
    if units_check is None:  # intervals chosen with the accel fit (IMU-TK rule) or accel in counts
        units_check = _units_check(settings, gyr_in, gyr_units_in, acc_fit.apply(np.asarray(ds["accel"].values)),
                                   iv, dts_clock, fs, ds, src, force, notes)
    if gset.get("enabled", True) and gyr_in is not None:
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
            rest = gyr_in[init_span[0]:init_span[1]]
            b0 = rest.mean(axis=0)
            if bias_mode == "initial":   # the standard error of a mean of the rest's samples
                off_cov = np.diag(rest.var(axis=0, ddof=1) / len(rest))
        if gset.get("dt", "nominal") == "timestamps":
            if "time" not in ds.coords:
                raise FieldCalError(f"{src}: gyro.dt = timestamps but the recording has no time coordinate")
            t = np.asarray(ds["time"].values, dtype=float)
            dts = np.concatenate([np.diff(t), [dt_nom]])
        else:
            dts = dts_clock
        gyr_fit = fit_gyro_directions(gyr_in, acc_cal, iv, dts, bias=b0, g_sensitivity=gsens,
                                      offset_covariance=off_cov, estimate_bias=(bias_mode == "estimate"),
                                      scale_guess=gset.get("scale_guess"), input_units=gyr_units_in,
                                      input_factor=gf, input_kind=gk, sample_dt=dt_nom,
                                      rank_rtol=float(settings.get("rank_rtol", 1e-6)), path=src,
                                      hold_undetermined=bool(settings.get("hold_undetermined", True)))
        gyr_fit.notes.append({
            "g_sensitive": "offset b + G a: bias and g-sensitivity G from a least-squares fit of the static gyro "
                           "means to the calibrated accel means (independent of the direction residuals)",
            "initial": f"bias: mean of the initial rest, samples [{init_span[0]}, {init_span[1]}) (IMU-TK)",
            "estimate": f"bias: estimated, starting from the initial-rest mean [{init_span[0]}, {init_span[1]})",
            "statics": "bias: mean over all static samples"}[bias_mode])
        gyr_fit.notes.append(f"integration step: {gset.get('dt', 'nominal')}")
        gyr_fit.extra["bias_mode"] = bias_mode
        if bias_mode in ("initial", "estimate"):   # the samples the bias starts from: its bound (calib.fieldcal.bound)
            gyr_fit.extra["bias_span"] = (int(init_span[0]), int(init_span[1]))
        gyr_fit.extra["integration_dt"] = dts   # the steps integrated: the gravity-direction bound uses the same
        metrics["gyro_direction_rms_deg"] = gyr_fit.residual_rms
        metrics["gyro_direction_rms_before_deg"] = gyr_fit.extra["rms_before_deg"]
        metrics["gyro_direction_max_deg"] = float(np.max(gyr_fit.extra["pair_angles_deg"]))
    return acc_fit, gyr_fit, iv, rule, units_check


def _norm_default(inp: _Inputs, notes: list, metrics: dict):
    """The norm method with the detection chosen as :mod:`calib.fieldcal.default_detection` describes: candidates
    ranked by their accel fit, then the full calibration of the best, the next when its result fails the checks.
    Returns what :func:`_norm` does and the ``detection_choice``. A result whose accel fit leaves parameters not
    determined gives way to the next candidate's that determines them all (the first such result is kept
    otherwise). When no candidate's result passes the checks:
    the units-check refusal when every candidate tried was refused by it (exit 2); else the first result that the
    result checks (:func:`calib.signal.plausibility.check_fieldcal_result`) refuse, marked failed, for the caller
    to write and refuse (``calib fieldcal``: exit 3); else a :class:`calib.core.errors.ResultCheckError` naming
    the settings."""
    settings, src = inp.settings, inp.src
    protocol = default_detection.protocol_of(inp.ds, settings, src)
    min_poses = int(settings.get("min_intervals", MIN_INTERVALS))
    need = int(settings.get("recommended_intervals", RECOMMENDED_INTERVALS))
    if protocol.n_poses is not None:
        need = min(need, protocol.n_poses + 1)   # the poses and the initial rest
    need = max(need, min_poses)
    cands = default_detection.candidates(inp.acc_in, inp.gyr_in, inp.fs, protocol,
                                         settings.get("samples_per_interval"))
    acc_attrs = inp.ds["accel"].attrs
    counts_per_g = acc_attrs.get("approx_counts_per_g")
    zero = acc_attrs.get("approx_zero_count")
    counts_per_g = None if counts_per_g is None else float(counts_per_g)
    zero = None if zero is None else float(zero)
    counts = inp.acc_units_in == "count"
    ranking = default_detection.rank(cands, inp.acc_in, inp.g, need=need, min_poses=min_poses, accel_counts=counts,
                                     counts_per_g=counts_per_g, zero_count=zero)
    for c in cands:  # IMU-TK's own search asks for 12 intervals: the candidate's settings ask for what it has
        if c.rule == "imu_tk" and c.fitted and len(c.intervals) < IMU_TK_DEFAULTS["min_intervals"]:
            c.detection["min_intervals"] = max(int(len(c.intervals)), min_poses)
    tries = ranking.order[:default_detection.FULL_ATTEMPTS] or ranking.fallback[:1]
    attempts, refusals, failed, partial = [], [], None, None
    for cand in tries:
        n2, m2 = list(notes), dict(metrics)
        with default_detection.held_messages() as said:
            try:
                # from the ranking's fit: with as few poses as parameters the ellipsoid start can be far off (when
                # the means do not span every direction, the full fit's own start, which holds what they cannot see)
                acc_fit, gyr_fit, iv, rule, uc = _norm(inp, cand.detection, n2, m2, x0=cand.start)
            except UnitsCheckError as exc:
                refusals.append(exc)
                attempts.append((cand, f"units check refused ({exc.field}): {exc.message}"))
                continue
            except (detect.StaticDetectionError, FieldCalError, np.linalg.LinAlgError) as exc:
                attempts.append((cand, str(exc)))
                continue
        checked = []   # what calib fieldcal's result check refuses
        try:
            plausibility.check_fieldcal_result(SimpleNamespace(accel=acc_fit, gyro=gyr_fit), counts,
                                               inp.gyr_units_in == "count", src)
        except ResultCheckError as exc:
            checked.append(exc.message)
        extra = default_detection.nominal_problems(acc_fit, counts_per_g, zero) if counts else []
        if checked or extra:
            attempts.append((cand, "; ".join(checked + extra)))
            if checked and failed is None:
                failed = (cand, (acc_fit, gyr_fit, iv, rule, uc), n2, m2, said, "; ".join(checked + extra))
            continue
        if acc_fit.determination is not None and acc_fit.determination.held:
            # a pose set on the edge of determining the model: a detection nearly as good may determine it all
            if partial is None:
                partial = (cand, (acc_fit, gyr_fit, iv, rule, uc), n2, m2, said)
            attempts.append((cand, "accel " + ", ".join(acc_fit.determination.held) + " not determined"))
            continue
        return _chosen(cand, (acc_fit, gyr_fit, iv, rule, uc), n2, m2, said, notes, metrics, cands, ranking,
                       attempts, protocol, src)
    if partial is not None:
        return _chosen(*partial, notes, metrics, cands, ranking, attempts, protocol, src)
    if refusals and len(refusals) == len(attempts):
        raise refusals[0]
    if failed is not None:
        cand, out, n2, m2, said, problems = failed
        return _chosen(cand, out, n2, m2, said, notes, metrics, cands, ranking, attempts, protocol, src,
                       status="failed", problems=problems)
    raise default_detection.no_choice_error(cands, src, ranking, protocol, attempts)


def _chosen(cand, out, n2, m2, said, notes, metrics, cands, ranking, attempts, protocol, src, status="passed",
            problems=""):
    """The result of the candidate ``cand`` (what :func:`_norm` returned, its notes ``n2``, metrics ``m2`` and
    held messages ``said``) as the session's, with the ``detection_choice``."""
    acc_fit, gyr_fit, iv, rule, uc = out
    notes[:] = n2
    metrics.clear()
    metrics.update(m2)
    default_detection.replay(said)
    choice = default_detection.choice(cand, cands, ranking, attempts, protocol, status=status, problems=problems)
    if status == "failed":
        notes.append(f"detection chosen without settings failed the result checks: {problems} -- fix: "
                     f"{default_detection.FIX}")
        log.warning("%s: %s", src, choice["line"])
    else:
        if cand.n_poses < ranking.need:
            notes.append(f"detection chosen without settings: no candidate detection finds {ranking.need} distinct "
                         f"poses; the one with the most ({cand.n_poses}) is used")
        log.info("%s: %s", src, choice["line"])
    return acc_fit, gyr_fit, iv, "chosen without detection settings (detection_choice): " + rule, uc, choice


def fieldcal_recording(path_or_ds, settings: dict | None = None, *, force: bool = False) -> FieldCalResult:
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
    for the smallest cost). No ``detection`` (or an empty one): chosen among candidate detections by their
    validated accel residual (:mod:`calib.fieldcal.default_detection`; the choice is logged, stored in the
    result's ``detection_choice`` and its summary). When no candidate's result passes the result checks
    (:func:`calib.signal.plausibility.check_fieldcal_result`), the best ranked one is returned with
    ``detection_choice['status'] == 'failed'`` and a note, for ``calib fieldcal`` to write and refuse (exit 3);
    when there is none to return (no candidate with ``min_intervals`` distinct poses), a
    :class:`calib.core.errors.ResultCheckError` (exit 3) names the settings keys to set.
    ``protocol``: ``{initial_rest_s, min_wait_s, n_poses}``, the session's timing as far as known (else the
    recording's ``protocol_<key>`` attributes); used by the default detection.
    ``samples_per_interval``: with rule ``detect``, fit on the first n samples of each interval (None: all).
    ``min_intervals`` (9: also the fewest distinct poses the default detection accepts), ``recommended_intervals``
    (12; the default detection prefers candidates with that many distinct poses and says so when none has them),
    ``rank_rtol`` (1e-6).
    ``gyro``: ``{enabled: true, bias: g_sensitive | initial | statics | estimate, dt: nominal | timestamps,
    scale_guess: input units per rad s-1}``. ``g_sensitive`` (default): offset ``b + G a`` with ``b`` and the
    g-sensitivity ``G`` fitted to the static gyro means against the calibrated accel means
    (:func:`gyro_static_regression`; falls back to ``statics`` when the orientations do not determine it);
    ``initial`` = mean over the initial rest (IMU-TK: its first ``init_samples + 1`` samples);
    ``estimate`` = that, refined in the direction fit; ``statics`` = mean over all static samples.
    ``units_check`` (default true): before the gyro fit, check the gyro's declared units and the recording's
    rate by rotation (:mod:`calib.fieldcal.units_check`: the common gyro factor that closes the gravity
    directions of consecutive static poses; 180/pi, pi/180, 2 or 1/2 name the mistake); a refusal is an
    :class:`calib.core.errors.InputError` (exit 2), a warning with ``force``; false: not run.
    ``hold_undetermined`` (default true): parameters the poses do not determine (marginal standard error above
    a plausibility scale: misalignment 1 deg, scale factor 1 %, bias 0.1 g or 10 deg/s) are held at nominal
    and the others refitted (the result's ``determination`` of each triad says which and why).
    Integration steps: ``gyro.dt: nominal`` is the recording's clock, 1 / ``sample_rate_hz`` per period (k
    periods over k - 1 dropped samples when the time coordinate has them).
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
    if "accel" not in ds:
        raise FieldCalError(f"{src}: variable 'accel': the recording holds gyroscopes only (absent_sensors); the "
                            "field calibration needs the accelerometer (the gravity norm at rest defines the poses) "
                            "-- fix: give a recording with the accelerometer; a gyro-only static record gives its "
                            "noise terms with calib noise")
    au, af, ak = _units_of(ds, "accel")
    acc_in = np.asarray(ds["accel"].values, dtype=np.float64) * af
    if ak == "increment":
        acc_in = acc_in / dt_nom
    acc_units_in = "count" if au == "count" else "m s-2"
    no_gyro = "gyro" not in ds   # an accelerometer-only partial record: the accelerometer calibration alone
    if no_gyro:
        gu, gf, gk, gyr_in, gyr_units_in = None, None, None, None, None
        if settings.get("method") == "ferraris":
            raise FieldCalError(f"{src}: settings 'method' = ferraris needs the gyro's turns and the recording holds "
                                "accelerometers only (absent_sensors) -- fix: method: norm (or auto)")
    else:
        gu, gf, gk = _units_of(ds, "gyro")
        gyr_in = np.asarray(ds["gyro"].values, dtype=np.float64) * gf
        if gk == "increment":
            gyr_in = gyr_in / dt_nom
        gyr_units_in = "count" if gu == "count" else "rad s-1"
    steps = clock_steps(ds, src)
    dts_clock = np.full(len(acc_in), dt_nom) if steps is None else np.concatenate([steps * dt_nom, [dt_nom]])
    units_check = choice = None
    method = settings.get("method", "auto")
    statics, turns = _labelled(ds)
    if method == "auto":
        method = "ferraris" if len(statics) == 6 and len(turns) == 3 and not no_gyro else "norm"
    gset = settings.get("gyro") or {}
    notes = [f"gravity {g:.6g} m s-2 from {g_src}"]
    if no_gyro:
        notes.append(NO_GYRO_NOTE)
        log.warning("%s: %s", src, NO_GYRO_NOTE)
    metrics = {}
    sensor = str(ds.attrs.get("sensor", ""))

    if method == "ferraris":
        iv_lab = np.array([[idx[0], idx[-1] + 1] for lab, idx in sorted(statics.items(), key=lambda kv: kv[1][0])])
        units_check = _units_check(settings, gyr_in, gyr_units_in, acc_in if acc_units_in != "count" else None,
                                   iv_lab, dts_clock, fs, ds, src, force, notes)
        acc_fit, gyr_fit = fit_ferraris(acc_in, gyr_in, fs, statics, turns, g, accel_units=acc_units_in,
                                        accel_factor=af, gyro_units=gyr_units_in, gyro_factor=gf,
                                        input_kind=ak, dt=dt_nom, path=src)
        iv = np.array([[idx[0], idx[-1] + 1] for lab, idx in sorted(statics.items(), key=lambda kv: kv[1][0])])
        frame = ("frame of the labelled case axes: x, y, z are the directions held up in x_p, y_p, z_p (assumed "
                 "orthogonal, as the Ferraris method does); gyro output in the same frame")
        rule = "segment labels of the recording (imucal x_p ... z_a, x_rot ... z_rot)"
        metrics["static_norm_rms_m_s2"] = acc_fit.residual_rms
        metrics["static_position_mean_norm_rms_m_s2"] = float(np.sqrt(np.mean(
            (np.linalg.norm(acc_fit.correction().correct(np.array([acc_in[statics[lab]].mean(axis=0)
                                                                  for lab in statics])), axis=1) - g) ** 2)))
        metrics["turn_angles_deg"] = {k: [float(x) for x in v] for k, v in gyr_fit.extra["turn_angles_deg"].items()}
        if not gset.get("enabled", True):
            gyr_fit = None
    else:
        inp = _Inputs(ds, src, settings, force, fs, dt_nom, g, acc_in, gyr_in, af, ak, gf, gk, acc_units_in,
                      gyr_units_in, dts_clock)
        if settings.get("detection"):
            acc_fit, gyr_fit, iv, rule, units_check = _norm(inp, settings["detection"], notes, metrics)
        else:
            acc_fit, gyr_fit, iv, rule, units_check, choice = _norm_default(inp, notes, metrics)
        frame = ("accelerometer-triad frame (IMU-TK convention): body x = accel x axis, body y in the plane of the "
                 "accel x and y axes, body z completing a right-handed orthogonal frame; gyro output in the same "
                 "frame (its misalignment includes the gyro-to-accel alignment)")
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
    if method == "norm":   # the Cramér–Rao bound beside every parameter (calib.fieldcal.bound)
        fieldcal_bound.attach(acc_fit, gyr_fit, acc_in, gyr_in, ds["accel"].values, iv, g)
    metrics["runtime_s"] = _time.perf_counter() - t_start
    return FieldCalResult(method=method, accel=acc_fit, gyro=gyr_fit, frame=frame, gravity_m_s2=g,
                          intervals=np.asarray(iv, dtype=np.int64).reshape(-1, 2), detection_rule=rule, source=src,
                          sensor=sensor, metrics=metrics, notes=notes,
                          settings={k: v for k, v in settings.items() if not k.startswith("_")},
                          units_check=units_check, detection_choice=choice)
