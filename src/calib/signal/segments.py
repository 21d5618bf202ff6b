"""Segment means of a ``calib-recording-1`` dataset: the observations every calibration works on.

* Static positions: the mean of the *rate reading* per static segment, per axis, with its standard deviation
  from the Allan deviation at tau = segment duration (``allan.py`` eq. 1). For increment channels
  (``sample_kind = increment``, units ``count``) the rate reading is ``N = counts / dt`` in ``count s-1``
  (Liu 2021's N); for rate channels it is the sample itself.
* Rotation segments: the mean over *whole revolutions* of the table, cut with ``table_angle``
  (``|angle - angle_start|`` = k x 360 deg), so the Earth-rate components perpendicular to the rotation
  axis average out (Liu 2021 eqs. 21-23); each with its signed table rate [deg/s, right-hand rule] and
  its axis (unit vector, body frame).
* Rotation pairs: a + and a - rotation about the same axis at the same |rate| (Liu 2021 eqs. 23-26).

Frames: body frame of the unit (Liu 2021: right-front-up); nominal attitudes are C_b^n (body to ENU).
The noise (sigma of each mean) comes from the Allan deviation pooled over all static segments of the same
sensor (so it includes bias instability and random walk, not just the white scatter inside one window).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from calib.signal import allan
from calib.core import earth
from calib.core.earth import STANDARD_GRAVITY
from calib.io.recording import unit_factor
from calib.core.triad import INPUT_UNITS
from calib.signal import detect


class SegmentError(ValueError):
    """Data that cannot give the segment means a calibration needs; the message says what to fix."""


RATE_UNIT_OF_INCREMENT = {"count": "count s-1", "m s-1": "m s-2", "rad": "rad s-1", "deg": "deg s-1"}


def _where(ds) -> str:
    return str(ds.attrs.get("_path", "<in-memory recording>"))


def rate_reading(ds, sensor: str):
    """Rate reading (n, 3) float64 of ``sensor`` ('accel'|'gyro') and its unit.

    Increment samples are divided by dt (counts -> count s-1, m s-1 -> m s-2, rad -> rad s-1, deg -> deg s-1).
    """
    if sensor not in ("accel", "gyro"):
        raise ValueError(f"sensor must be 'accel' or 'gyro', got {sensor!r}")
    if sensor not in ds:
        raise SegmentError(f"{_where(ds)}: variable '{sensor}' missing")
    v = ds[sensor]
    kind = v.attrs.get("sample_kind")
    units = v.attrs.get("units")
    fs = float(ds.attrs["sample_rate_hz"])
    y = np.asarray(v.values, dtype=np.float64)
    if kind == "increment":
        return y * fs, RATE_UNIT_OF_INCREMENT.get(units, f"{units} s-1")
    return y, units


def input_unit_for(sensor: str, output_unit: str) -> str:
    """Input unit of the triad model N = K E x + b: for count outputs the synthetic unit's (g, deg h-1,
    see ``sensors.INPUT_UNITS``); for physical outputs the output unit itself (K ~ 1)."""
    if output_unit.startswith("count"):
        return INPUT_UNITS[sensor][0]
    return output_unit


def reference_magnitude(sensor: str, input_unit: str, latitude_deg: float, height_m: float = 0.0,
                        gravity_m_s2: float | None = None) -> float:
    """|input| at rest in ``input_unit``: local normal gravity (accel) or Earth rate (gyro), Liu 2021 eq. 5.

    Gravity: WGS-84 normal gravity (or the recording's ``gravity_m_s2``); in ``g`` it is gamma / 9.80665.
    Earth rate: 7.292115e-5 rad/s = 15.041 deg/h.
    """
    if sensor == "accel":
        g = gravity_m_s2 if gravity_m_s2 is not None else float(earth.normal_gravity(math.radians(latitude_deg),
                                                                                    height_m))
        f = STANDARD_GRAVITY if input_unit == "g" else unit_factor(input_unit)
        if f is None or input_unit not in ("g", "m s-2"):
            raise SegmentError(f"accel input unit {input_unit!r} is not a specific-force unit (g or m s-2)")
        return g / f
    f = unit_factor(input_unit)
    if f is None or input_unit not in ("rad s-1", "deg s-1", "deg h-1"):
        raise SegmentError(f"gyro input unit {input_unit!r} is not an angular-rate unit (rad s-1, deg s-1, deg h-1)")
    return earth.OMEGA_IE / f


def to_input_unit(values_si, input_unit: str):
    """SI values (m s-2 or rad s-1) in ``input_unit``."""
    f = STANDARD_GRAVITY if input_unit == "g" else unit_factor(input_unit)
    return np.asarray(values_si, dtype=float) / f


@dataclass
class StaticMeans:
    """Per-static-position means of one triad.

    ``means`` (M, 3) rate reading [output_unit]; ``sigma`` (M, 3) std of each mean [output_unit];
    ``duration_s`` (M,); ``attitude`` (M, 3, 3) nominal C_b^n or None; ``reference`` |input| at rest
    [input_unit] (g or Omega, Liu 2021 eq. 5). ``t_start_s`` (M,) start of each averaged window [s from the
    recording's first sample] (None for closed-form means); ``cov_axes`` (3, M, M) full covariance of the means
    per axis [output_unit^2] when a noise model with the slow part is attached (``calib.signal.noisecov``), else None
    (independent means with std ``sigma``).
    """

    sensor: str
    means: np.ndarray
    sigma: np.ndarray
    duration_s: np.ndarray
    reference: float
    input_unit: str
    output_unit: str
    latitude_deg: float
    attitude: np.ndarray | None = None
    labels: list = field(default_factory=list)
    segment: np.ndarray | None = None
    noise: allan.AllanResult | None = None
    source: str = ""
    t_start_s: np.ndarray | None = None
    cov_axes: np.ndarray | None = None

    @property
    def n(self) -> int:
        return self.means.shape[0]

    def true_inputs(self):
        """Nominal input per position in the body frame [input_unit]: f^b = C_n^b (0, 0, g) (accel) or
        omega_ie^b = C_n^b omega_ie^n (gyro). Needs ``attitude``."""
        if self.attitude is None:
            raise SegmentError(f"{self.source or self.sensor}: no nominal attitudes (variable nominal_attitude) - "
                               "a vector calibration needs the table attitude of every static position; "
                               "use the norm calibration instead or add the segment table's attitudes")
        lat = math.radians(self.latitude_deg)
        if self.sensor == "accel":
            v_n = np.array([0.0, 0.0, self.reference])
        else:
            v_n = earth.earth_rate_enu(lat) / earth.OMEGA_IE * self.reference
        return np.einsum("mji,j->mi", self.attitude, v_n)  # C_n^b v_n = (C_b^n)^T v_n


@dataclass
class RotationMeans:
    """Whole-revolution means of rotation segments (Liu 2021 eqs. 21-23).

    ``means`` (J, 3) [output_unit]; ``sigma`` (J, 3); ``axis`` (J, 3) unit vector in the body frame;
    ``rate_deg_s`` (J,) signed by the right-hand rule about ``axis``; ``revolutions`` (J,) whole turns
    averaged; ``attitude`` (J, 3, 3) C_b^n at the segment start or None; ``t_start_s`` (J,) start of each
    whole-revolution window [s from the recording's first sample] (None for closed-form means).
    """

    sensor: str
    means: np.ndarray
    sigma: np.ndarray
    axis: np.ndarray
    rate_deg_s: np.ndarray
    revolutions: np.ndarray
    duration_s: np.ndarray
    input_unit: str
    output_unit: str
    latitude_deg: float
    attitude: np.ndarray | None = None
    labels: list = field(default_factory=list)
    segment: np.ndarray | None = None
    source: str = ""
    t_start_s: np.ndarray | None = None

    @property
    def n(self) -> int:
        return self.means.shape[0]

    def table_rate_input(self):
        """Table rate vector in the body frame in the input unit, (J, 3)."""
        return to_input_unit(self.rate_deg_s[:, None] * math.radians(1.0) * self.axis, self.input_unit)

    def mean_inputs(self):
        """Mean body-frame input over whole revolutions [input_unit]: table rate + the Earth-rate component
        along the axis (the perpendicular part averages to zero, Liu 2021 eq. 23). Needs ``attitude``."""
        if self.attitude is None:
            raise SegmentError(f"{self.source or 'rotations'}: no nominal attitude for the rotation segments - the "
                               "Earth-rate component along the rotation axis is unknown; add nominal_attitude")
        w_ie_n = to_input_unit(earth.earth_rate_enu(math.radians(self.latitude_deg)), self.input_unit)
        axis_n = np.einsum("mij,mj->mi", self.attitude, self.axis)
        along = axis_n @ w_ie_n
        return self.table_rate_input() + along[:, None] * self.axis


@dataclass
class RotationPairs:
    """Matched + / - rotations about the same axis (Liu 2021 eqs. 23-26).

    ``plus``/``minus`` (J, 3) whole-revolution means; ``sigma_plus``/``sigma_minus``; ``axis`` (J, 3) body frame;
    ``rate_plus``/``rate_minus`` (J,) signed deg/s about ``axis``; ``attitude`` C_b^n of the + segment;
    ``t_plus``/``t_minus`` (J,) window starts [s from the recording's first sample] and
    ``duration_plus``/``duration_minus`` (J,) [s] (None for closed-form pairs).
    """

    plus: np.ndarray
    minus: np.ndarray
    sigma_plus: np.ndarray
    sigma_minus: np.ndarray
    axis: np.ndarray
    rate_plus: np.ndarray
    rate_minus: np.ndarray
    input_unit: str
    output_unit: str
    latitude_deg: float
    attitude: np.ndarray | None = None
    attitude_minus: np.ndarray | None = None
    labels: list = field(default_factory=list)
    unpaired: list = field(default_factory=list)
    t_plus: np.ndarray | None = None
    t_minus: np.ndarray | None = None
    duration_plus: np.ndarray | None = None
    duration_minus: np.ndarray | None = None

    @property
    def n(self) -> int:
        return self.plus.shape[0]

    def difference(self):
        """N+ - N- (J, 3) and its sigma (Liu 2021 eq. 25 numerators); the bias cancels."""
        return self.plus - self.minus, np.hypot(self.sigma_plus, self.sigma_minus)

    def delta_input(self):
        """Input difference (J, 3) [input_unit]: (r+ - r-) * axis = 2 omega_0^b of Liu 2021 eq. 26."""
        d = (self.rate_plus - self.rate_minus)[:, None] * math.radians(1.0) * self.axis
        return to_input_unit(d, self.input_unit)

    def pair_mean(self):
        """(N+ + N-)/2 (J, 3) and its sigma: K E (mean input) + b (Liu 2021 eqs. 23 + 24)."""
        return 0.5 * (self.plus + self.minus), 0.5 * np.hypot(self.sigma_plus, self.sigma_minus)

    def mean_input(self):
        """Mean body input of the pair [input_unit]: (r+ + r-)/2 * axis + Earth rate along the axis."""
        if self.attitude is None:
            raise SegmentError("rotation pairs have no nominal attitude: the Earth-rate component along the axis is "
                               "unknown; add nominal_attitude or take the biases from the static positions")
        w_ie_n = to_input_unit(earth.earth_rate_enu(math.radians(self.latitude_deg)), self.input_unit)
        along = np.einsum("mij,mj->mi", self.attitude, self.axis) @ w_ie_n
        if self.attitude_minus is not None:
            along = 0.5 * (along + np.einsum("mij,mj->mi", self.attitude_minus, self.axis) @ w_ie_n)
        tab = 0.5 * (self.rate_plus + self.rate_minus)[:, None] * math.radians(1.0) * self.axis
        return to_input_unit(tab, self.input_unit) + along[:, None] * self.axis


# ----------------------------------------------------------------------------------------------------------
def _segment_table(ds):
    """(segment_index per sample, kinds list, labels list) from the recording, or via calib.signal.detect."""
    if "segment_index" in ds and "segment_kind" in ds:
        si = np.asarray(ds["segment_index"].values, dtype=np.int64)
        kinds = [str(k) for k in ds["segment_kind"].values]
        labels = ([str(s) for s in ds["segment_label"].values] if "segment_label" in ds
                  else [f"segment {i}" for i in range(len(kinds))])
        return si, kinds, labels
    acc, _ = rate_reading(ds, "accel")
    gyr, _ = rate_reading(ds, "gyro")
    try:
        found = detect.detect_static(acc, gyr, float(ds.attrs["sample_rate_hz"]))
    except ValueError as exc:
        raise SegmentError(f"{_where(ds)}: no segment table, and the static detector failed: {exc}") from exc
    found = getattr(found, "intervals", found)  # StaticDetection.intervals: (m, 2) [start, stop) indices
    n = ds.sizes["time"]
    si = np.full(n, -1, dtype=np.int64)
    for k, (a, b) in enumerate(np.asarray(found, dtype=np.int64).reshape(-1, 2)):
        si[int(a):int(b)] = k
    nseg = int(si.max()) + 1 if si.size else 0
    return si, ["static"] * nseg, [f"detected static {k}" for k in range(nseg)]


def _window_start(ds, i0: int) -> float:
    """Time of sample ``i0`` [s] from the recording's first sample."""
    if "time" in ds.coords or "time" in ds:
        t = ds["time"]
        return float(t.values[i0] - t.values[0])
    return i0 / float(ds.attrs["sample_rate_hz"])


def _check_not_flat(y, sensor, where):
    if y.shape[0] < 3:
        raise SegmentError(f"{where}: variable '{sensor}': only {y.shape[0]} samples")
    # every column's peak-to-peak span is 0 (np.ptp(y, axis=0) == 0, a slow strided reduction) exactly when every
    # sample equals the first and the first is finite (an infinite column has a NaN span)
    if bool((y[:64] == y[0]).all()) and np.all(np.isfinite(y[0])) and bool((y == y[0]).all()):
        raise SegmentError(f"{where}: variable '{sensor}': every sample is identical ({y[0]}) - the data are flat "
                           "(dead or disconnected channel, or wrong variable); nothing can be calibrated")


def noise_from_static(ds, sensor: str, *, trim_s: float = 0.0, confidence: float = 0.95) -> allan.AllanResult:
    """Allan deviation of ``sensor`` pooled over all static segments (``allan.adev_pooled``)."""
    y, unit = rate_reading(ds, sensor)
    fs = float(ds.attrs["sample_rate_hz"])
    si, kinds, _ = _segment_table(ds)
    trim = int(round(trim_s * fs))
    recs = []
    for s, k in enumerate(kinds):
        if k != "static":
            continue
        idx = np.flatnonzero(si == s)
        if trim:
            idx = idx[trim:len(idx) - trim]
        if len(idx) >= 3:
            recs.append(y[idx])
    if not recs:
        raise SegmentError(f"{_where(ds)}: no static segment with at least 3 samples for the noise estimate")
    try:
        return allan.adev_pooled(recs, fs, confidence=confidence, unit=unit)
    except allan.AllanError as exc:
        raise SegmentError(f"{_where(ds)}: variable '{sensor}': {exc}") from exc


def static_means(ds, sensor: str, *, noise: allan.AllanResult | None = None, sigma=None, trim_s: float = 0.0,
                 input_unit: str | None = None, min_samples: int = 3) -> StaticMeans:
    """Means of the rate reading per static segment with their sigma.

    ``noise``: an Allan result to take sigma from (default: pooled over this recording's static segments);
    ``sigma``: override, (3,) or (M, 3) in the output unit. ``trim_s`` drops that much at each segment end.
    """
    where = _where(ds)
    y, out_unit = rate_reading(ds, sensor)
    _check_not_flat(y, sensor, where)
    fs = float(ds.attrs["sample_rate_hz"])
    si, kinds, labels = _segment_table(ds)
    trim = int(round(trim_s * fs))
    means, dur, segs, labs, t0s = [], [], [], [], []
    for s, k in enumerate(kinds):
        if k != "static":
            continue
        idx = np.flatnonzero(si == s)
        if trim:
            idx = idx[trim:len(idx) - trim]
        if len(idx) < min_samples:
            continue
        t0s.append(_window_start(ds, int(idx[0])))
        means.append(y[idx].mean(axis=0))
        dur.append(len(idx) / fs)
        segs.append(s)
        labs.append(labels[s])
    if not means:
        raise SegmentError(f"{where}: no static segment with at least {min_samples} samples (segment_kind has "
                           f"{kinds.count('static')} static entries)")
    means = np.array(means)
    dur = np.array(dur)
    if sigma is not None:
        sig = np.broadcast_to(np.asarray(sigma, dtype=float), means.shape).copy()
        noise_used = None
    else:
        noise_used = noise or noise_from_static(ds, sensor, trim_s=trim_s)
        sig = noise_used.sigma_of_mean(dur)
    if np.any(~(sig > 0)):
        raise SegmentError(f"{where}: variable '{sensor}': zero sigma for a static mean - flat data; give sigma "
                           "explicitly if the channel is really noise-free")
    att = None
    if "nominal_attitude" in ds:
        att = np.asarray(ds["nominal_attitude"].values, dtype=float)[segs]
    in_unit = input_unit or input_unit_for(sensor, out_unit)
    lat = float(ds.attrs["latitude_deg"])
    h = float(ds.attrs.get("height_m", 0.0))
    gref = ds.attrs.get("gravity_m_s2")
    ref = reference_magnitude(sensor, in_unit, lat, h, None if gref is None else float(gref))
    if len(means) > 1 and np.all(np.ptp(means, axis=0) <= 3.0 * sig.max(axis=0)):
        raise SegmentError(f"{where}: variable '{sensor}': the {len(means)} static means do not differ beyond the "
                           "noise - the unit was not turned between positions (flat data); a calibration needs "
                           "positions with different orientations")
    return StaticMeans(sensor=sensor, means=means, sigma=sig, duration_s=dur, reference=ref, input_unit=in_unit,
                       output_unit=out_unit, latitude_deg=lat, attitude=att, labels=labs, segment=np.array(segs),
                       noise=noise_used, source=where, t_start_s=np.array(t0s))


def whole_revolution_window(angle_deg, rate_deg_s: float, dt: float):
    """Number of samples ``n`` from the segment start spanning whole revolutions, and the revolutions k.

    ``angle_deg`` table angle per sample of the segment (unwrapped here). The window is samples [0, n) with
    |angle[n] - angle[0]| = k * 360 deg to within half a sample step (or the end of the segment).
    """
    a = np.rad2deg(np.unwrap(np.deg2rad(np.asarray(angle_deg, dtype=float))))
    rel = np.abs(a - a[0])
    step = abs(rate_deg_s) * dt
    tol = 0.5 * step + 1e-9
    # the last sample's increment covers one more step than its angle stamp shows
    total = rel[-1] + step
    k = int(math.floor((total + tol) / 360.0))
    if k < 1:
        return 0, 0
    target = k * 360.0
    hit = np.flatnonzero(rel >= target - tol)
    n = int(hit[0]) if hit.size else len(a)
    return n, k


def rotation_means(ds, sensor: str = "gyro", *, noise: allan.AllanResult | None = None, sigma=None,
                   input_unit: str | None = None) -> RotationMeans:
    """Whole-revolution means of every rotation segment (cut with ``table_angle``; without it the nominal
    angle rate x time is used)."""
    where = _where(ds)
    y, out_unit = rate_reading(ds, sensor)
    _check_not_flat(y, sensor, where)
    fs = float(ds.attrs["sample_rate_hz"])
    dt = 1.0 / fs
    si, kinds, labels = _segment_table(ds)
    rot = [s for s, k in enumerate(kinds) if k == "rotation"]
    if not rot:
        raise SegmentError(f"{where}: no rotation segment (segment_kind = 'rotation') - the dynamic gyro "
                           "calibration needs + and - rotations about three axes")
    if "rotation_rate" not in ds:
        raise SegmentError(f"{where}: variable 'rotation_rate' missing - give the table rate of every rotation "
                           "segment in deg/s (right-hand rule)")
    if "rotation_axis" not in ds:
        raise SegmentError(f"{where}: variable 'rotation_axis' missing - give the body-frame rotation axis of "
                           "every rotation segment")
    rates = np.asarray(ds["rotation_rate"].values, dtype=float)
    axes = np.asarray(ds["rotation_axis"].values, dtype=float)
    ang_all = np.asarray(ds["table_angle"].values, dtype=float) if "table_angle" in ds else None
    means, dur, revs, segs, labs, ax_out, rt_out, t0s = [], [], [], [], [], [], [], []
    for s in rot:
        r = rates[s]
        if not (np.isfinite(r) and r != 0.0):
            raise SegmentError(f"{where}: variable 'rotation_rate': rotation segment {s} ({labels[s]}) has no rate "
                               f"({r}) - give the table rate in deg/s, signed by the right-hand rule")
        a = axes[s]
        na = np.linalg.norm(a)
        if not (np.isfinite(na) and na > 0):
            raise SegmentError(f"{where}: variable 'rotation_axis': rotation segment {s} ({labels[s]}) has no axis")
        idx = np.flatnonzero(si == s)
        if len(idx) < 2:
            raise SegmentError(f"{where}: rotation segment {s} ({labels[s]}) has {len(idx)} samples")
        ang = ang_all[idx] if ang_all is not None else r * np.arange(len(idx)) * dt
        n, k = whole_revolution_window(ang, r, dt)
        if k < 1:
            raise SegmentError(f"{where}: rotation segment {s} ({labels[s]}) turns less than one whole revolution "
                               f"(|delta angle| = {abs(np.ptp(ang)):.1f} deg) - whole revolutions are needed for the "
                               "Earth rate to average out")
        w = idx[:n]
        t0s.append(_window_start(ds, int(w[0])))
        means.append(y[w].mean(axis=0))
        dur.append(n * dt)
        revs.append(k)
        segs.append(s)
        labs.append(labels[s])
        ax_out.append(a / na)
        rt_out.append(r)
    means = np.array(means)
    dur = np.array(dur)
    if sigma is not None:
        sig = np.broadcast_to(np.asarray(sigma, dtype=float), means.shape).copy()
    else:
        nz = noise or noise_from_static(ds, sensor)
        sig = nz.sigma_of_mean(dur)
    att = np.asarray(ds["nominal_attitude"].values, dtype=float)[segs] if "nominal_attitude" in ds else None
    return RotationMeans(sensor=sensor, means=means, sigma=sig, axis=np.array(ax_out), rate_deg_s=np.array(rt_out),
                         revolutions=np.array(revs), duration_s=dur,
                         input_unit=input_unit or input_unit_for(sensor, out_unit), output_unit=out_unit,
                         latitude_deg=float(ds.attrs["latitude_deg"]), attitude=att, labels=labs,
                         segment=np.array(segs), source=where, t_start_s=np.array(t0s))


def pair_rotations(rot: RotationMeans, rtol: float = 1e-3) -> RotationPairs:
    """Match each rotation with one of opposite signed rate vector (rate x axis) of equal size.

    Pairs are formed in recording order; the element with positive rate about the canonical axis direction
    (first non-zero component positive) is '+'. Unmatched segments are listed in ``unpaired``.
    """
    w = rot.rate_deg_s[:, None] * rot.axis
    used = np.zeros(rot.n, dtype=bool)
    P, Mi = [], []
    for i in range(rot.n):
        if used[i]:
            continue
        for j in range(i + 1, rot.n):
            if used[j]:
                continue
            if np.linalg.norm(w[i] + w[j]) <= rtol * np.linalg.norm(w[i]):
                used[i] = used[j] = True
                P.append(i)
                Mi.append(j)
                break
    if not P:
        raise SegmentError(f"{rot.source}: no pair of opposite rotations (same axis, same |rate|, opposite sense) "
                           "- eq. 25/26 need a + and a - rotation about each axis")
    P, Mi = np.array(P), np.array(Mi)
    # canonical axis direction: first clearly non-zero component positive; '+' has positive rate about it
    axis = rot.axis[P].copy()
    rp = rot.rate_deg_s[P].copy()
    rm = rot.rate_deg_s[Mi] * np.einsum("ij,ij->i", rot.axis[Mi], axis)  # rate of the - segment about axis
    for k in range(len(P)):
        c = axis[k][np.argmax(np.abs(axis[k]))]
        if c < 0:
            axis[k] *= -1
            rp[k] *= -1
            rm[k] *= -1
    swap = rp < 0
    plus_idx = np.where(swap, Mi, P)
    minus_idx = np.where(swap, P, Mi)
    rate_plus = np.where(swap, rm, rp)
    rate_minus = np.where(swap, rp, rm)
    att = rot.attitude
    return RotationPairs(plus=rot.means[plus_idx], minus=rot.means[minus_idx], sigma_plus=rot.sigma[plus_idx],
                         sigma_minus=rot.sigma[minus_idx], axis=axis, rate_plus=rate_plus, rate_minus=rate_minus,
                         input_unit=rot.input_unit, output_unit=rot.output_unit, latitude_deg=rot.latitude_deg,
                         attitude=None if att is None else att[plus_idx],
                         attitude_minus=None if att is None else att[minus_idx],
                         labels=[f"{rot.labels[a]} / {rot.labels[b]}" for a, b in zip(plus_idx, minus_idx)],
                         unpaired=[rot.labels[k] for k in np.flatnonzero(~used)],
                         t_plus=None if rot.t_start_s is None else rot.t_start_s[plus_idx],
                         t_minus=None if rot.t_start_s is None else rot.t_start_s[minus_idx],
                         duration_plus=rot.duration_s[plus_idx], duration_minus=rot.duration_s[minus_idx])


def require_positions(static: StaticMeans, needed: int, what: str):
    """Raise a clear error when fewer than ``needed`` static positions are available for ``what``."""
    if static.n < needed:
        raise SegmentError(f"{static.source or static.sensor}: {what} needs at least {needed} static positions "
                           f"with different orientations, found {static.n} - record more positions "
                           "(Liu 2021 uses 24)")


@dataclass
class CalibrationInputs:
    """Everything the calibrations need from one recording."""

    accel_static: StaticMeans
    gyro_static: StaticMeans
    gyro_rotations: RotationMeans | None
    gyro_pairs: RotationPairs | None
    accel_noise: allan.AllanResult
    gyro_noise: allan.AllanResult


def extract(ds, *, trim_s: float = 0.0) -> CalibrationInputs:
    """Static means of both triads, whole-revolution gyro means and pairs, Allan noise of both sensors."""
    an = noise_from_static(ds, "accel", trim_s=trim_s)
    gn = noise_from_static(ds, "gyro", trim_s=trim_s)
    a = static_means(ds, "accel", noise=an, trim_s=trim_s)
    g = static_means(ds, "gyro", noise=gn, trim_s=trim_s)
    kinds = [str(k) for k in ds["segment_kind"].values] if "segment_kind" in ds else []
    rot = pairs = None
    if "rotation" in kinds:
        rot = rotation_means(ds, "gyro", noise=gn)
        pairs = pair_rotations(rot)
    return CalibrationInputs(a, g, rot, pairs, an, gn)
