"""Units and rate checked by rotation, before the gyro fit.

Between two consecutive static poses the gyro, integrated in its *declared* units at the recording's clock
(nominal scale, no misalignment, the static bias of the two poses removed), must carry the gravity direction the
accelerometers measure at the first pose into the one they measure at the second. The single common factor ``s``
on the gyro that best closes all pairs (least squares on the closure angles, over ``s`` in [1/100, 100]: a
logarithmic grid, then :func:`scipy.optimize.minimize_scalar` around its best point) names a mislabelling:

* ``s`` near 180/pi: the data are in radians but declared in degrees (``gyro.units``); near pi/180 the reverse;
* ``s`` near 2 or 1/2: the declared ``sample_rate_hz`` is twice or half the true rate (with a rate fitted to the
  recording's timestamps: the gyro's scale, e.g. its full-scale range setting, is off by that factor);
* ``s`` within :data:`PASS_TOLERANCE` of 1 passes; any other factor is refused, named.

Refusals raise :class:`UnitsCheckError` (an :class:`calib.core.errors.InputError`, exit 2) unless forced.
The closure constrains only the rotation about axes not parallel to gravity: a pair whose gravity directions
differ by less than :data:`MIN_PAIR_ANGLE_DEG` carries no information and is skipped; with fewer than
:data:`MIN_PAIRS` informative pairs the check says "not checked" and why. Gyros in counts have no nominal scale
and are not checked.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from dataclasses import field as dc_field

import numba
import numpy as np
from scipy.optimize import minimize_scalar

from calib.core.errors import InputError
from calib.fieldcal.gyroscope import (
    direction_angles_deg,
    integrate_quaternions,
    quats_to_dcm,
    rk4_step,
)

MIN_PAIR_ANGLE_DEG = 10.0
MIN_PAIRS = 2
PASS_TOLERANCE = 0.05
#: a factor within this (relative) of a named factor is taken as that mistake
NAMED_TOLERANCE = 0.05
SCALE_RANGE = (1e-2, 1e2)
GRID_POINTS = 1201


class UnitsCheckError(InputError):
    """The gyro's declared units or the recording's rate contradict the rotation between static poses."""


@dataclass
class UnitsCheck:
    """Outcome of :func:`check_gyro_units`. ``status``: passed | refused | forced (refused, then overridden) |
    not checked | disabled. ``scale``: the common gyro factor that best closes the pairs (NaN when not checked).
    ``closure_deg``: per informative pair, the closure angle at the declared scale; ``closure_best_deg`` at
    ``scale``; ``pairs``: their pose numbers; ``gravity_angle_deg``: the angle between the two gravity
    directions of every consecutive pair (informative or not)."""

    status: str
    reason: str
    scale: float = float("nan")
    mistake: str = ""
    field: str = ""
    pairs: list = dc_field(default_factory=list)
    closure_deg: np.ndarray = dc_field(default_factory=lambda: np.zeros(0))
    closure_best_deg: np.ndarray = dc_field(default_factory=lambda: np.zeros(0))
    gravity_angle_deg: np.ndarray = dc_field(default_factory=lambda: np.zeros(0))

    def as_dict(self) -> dict:
        return {"status": self.status, "reason": self.reason,
                "scale": None if not math.isfinite(self.scale) else float(self.scale), "mistake": self.mistake,
                "field": self.field, "pairs": [list(map(int, p)) for p in self.pairs],
                "closure_deg": [round(float(v), 4) for v in self.closure_deg],
                "closure_best_deg": [round(float(v), 4) for v in self.closure_best_deg],
                "gravity_angle_deg": [round(float(v), 3) for v in self.gravity_angle_deg]}


def _pairs_problem(gyro, accel, intervals, dt):
    iv = np.asarray(intervals, dtype=np.int64).reshape(-1, 2)
    iv = iv[np.argsort(iv[:, 0])]
    u = np.array([accel[a:b].mean(axis=0) for a, b in iv])
    u = u / np.linalg.norm(u, axis=1)[:, None]
    bias = np.array([gyro[a:b].mean(axis=0) for a, b in iv])
    cosang = np.clip(np.sum(u[:-1] * u[1:], axis=1), -1.0, 1.0)
    gangle = np.degrees(np.arccos(cosang))
    return iv, u, bias, gangle


def _closure(gyro, dt, iv, u, bias, use):
    """closure(s) -> angles (deg) of the informative pairs ``use`` for the gyro scaled by s."""
    spans = [(iv[i, 1] - 1, iv[i + 1, 0]) for i in use]
    idx = np.concatenate([np.arange(a, b + 1) for a, b in spans])
    w0 = np.concatenate([gyro[a:b + 1] - 0.5 * (bias[i] + bias[i + 1]) for (a, b), i in zip(spans, use)])
    w0 = np.ascontiguousarray(w0, dtype=np.float64)
    step = np.ascontiguousarray(dt[idx], dtype=np.float64)
    lens = np.array([b - a + 1 for a, b in spans])
    starts = np.concatenate([[0], np.cumsum(lens)[:-1]]).astype(np.int64)
    stops = (starts + lens - 1).astype(np.int64)
    u0, u1 = u[use], u[use + 1]

    def from_quaternions(q):
        carried = np.einsum("mji,mj->mi", quats_to_dcm(q), u0)
        return direction_angles_deg(carried - u1)

    def angles(s):
        return from_quaternions(integrate_quaternions(w0 * s, step, starts, stops))

    def grid_cost(grid):
        """sum(angles(s)^2) for every s of ``grid``: the same numbers as calling ``angles`` per s (the rotations
        of all factors integrated in one compiled call, each by :func:`integrate_quaternions` on ``w0 * s``)."""
        q = _integrate_scaled(w0, step, starts, stops, np.ascontiguousarray(grid, dtype=np.float64))
        return np.array([float(np.sum(from_quaternions(q[k]) ** 2)) for k in range(len(grid))])

    angles.grid_cost = grid_cost
    return angles


@numba.njit(cache=True, error_model="numpy")
def _integrate_scaled(w0, step, starts, stops, scales):  # pragma: no cover - compiled
    """(len(scales), m, 4): :func:`integrate_quaternions` of ``w0 * s`` for every factor ``s`` of ``scales``, the
    factors side by side in the innermost loop (so that they run in vector lanes). Every factor sees the operations
    of :func:`integrate_quaternions` in its order (the rate ``w0 * s`` rounded as numpy rounds it), so the numbers
    are the same to the last bit (tests/fieldcal/test_units_check.py); ``error_model="numpy"`` only drops the
    zero-division check of the renormalisation (a unit quaternion's norm is never 0)."""
    ns = scales.shape[0]
    m = starts.shape[0]
    out = np.empty((ns, m, 4))
    q0 = np.empty(ns)
    q1 = np.empty(ns)
    q2 = np.empty(ns)
    q3 = np.empty(ns)
    for i in range(m):
        q0[:] = 1.0
        q1[:] = 0.0
        q2[:] = 0.0
        q3[:] = 0.0
        for j in range(starts[i], stops[i]):
            h = step[j]
            a0, a1, a2 = w0[j, 0], w0[j, 1], w0[j, 2]
            b0, b1, b2 = w0[j + 1, 0], w0[j + 1, 1], w0[j + 1, 2]
            for k in range(ns):
                s = scales[k]
                ax, ay, az = a0 * s, a1 * s, a2 * s
                bx, by, bz = b0 * s, b1 * s, b2 * s
                q0[k], q1[k], q2[k], q3[k] = rk4_step(q0[k], q1[k], q2[k], q3[k], ax, ay, az, bx, by, bz, h)
        for k in range(ns):
            out[k, i, 0], out[k, i, 1], out[k, i, 2], out[k, i, 3] = q0[k], q1[k], q2[k], q3[k]
    return out


def best_scale(angles, bounds=SCALE_RANGE, n_grid=GRID_POINTS) -> float:
    """The factor s in ``bounds`` minimising sum(angles(s)^2): logarithmic grid, then a bounded 1-D search on
    log s between the grid neighbours of the best grid point. ``angles.grid_cost(grid)``, when present, gives the
    grid's costs at once (the same numbers; :func:`_closure`)."""
    grid = np.exp(np.linspace(math.log(bounds[0]), math.log(bounds[1]), n_grid))
    many = getattr(angles, "grid_cost", None)
    cost = many(grid) if many is not None else np.array([float(np.sum(angles(s) ** 2)) for s in grid])
    k = int(np.argmin(cost))
    lo, hi = math.log(grid[max(k - 1, 0)]), math.log(grid[min(k + 1, n_grid - 1)])
    if hi <= lo:
        return float(grid[k])
    r = minimize_scalar(lambda x: float(np.sum(angles(math.exp(x)) ** 2)), bounds=(lo, hi), method="bounded",
                        options={"xatol": 1e-9})
    return float(math.exp(r.x)) if r.fun <= cost[k] else float(grid[k])


def _name(s, rate_from_clock, fs):
    """(field, mistake, fix) for factor s, or None when no mistake is named."""
    def near(x):
        return abs(s / x - 1.0) <= NAMED_TOLERANCE
    if near(180.0 / math.pi):
        return ("gyro.units", "the gyro data are in radians but declared in degrees (rad s-1 declared as deg s-1)",
                "declare gyro.units: 'rad s-1' (or 'rad' for increments)")
    if near(math.pi / 180.0):
        return ("gyro.units", "the gyro data are in degrees but declared in radians (deg s-1 declared as rad s-1)",
                "declare gyro.units: 'deg s-1' (or 'deg' for increments)")
    for x, word in ((2.0, "twice"), (0.5, "half")):
        if near(x):
            if rate_from_clock:
                return ("gyro.scale", (f"the gyro reads {1 / x:g} x the true rate (the sample rate is fitted to the "
                        "timestamps, so the gyro's scale is off, e.g. its full-scale range setting)"),
                        f"multiply gyro.scale by {x:g}")
            return ("sample_rate_hz", f"the declared sample rate ({fs:g} Hz) is {word} the true rate",
                    f"declare sample_rate_hz: {fs / x:g}")
    return None


def check_gyro_units(gyro_rad_s, accel, intervals, dt, *, source: str = "input", fs: float = float("nan"),
                     rate_from_clock: bool = False, force: bool = False) -> UnitsCheck:
    """Check the gyro's declared units and the recording's rate by rotation (module docstring).

    ``gyro_rad_s``: (n, 3) gyro in rad s-1 per the declared units; ``accel``: (n, 3) specific force whose mean
    direction at a pose is gravity's in the gyro's frame (calibrated, or raw in physical units); ``intervals``:
    the static poses ``[start, stop)``; ``dt``: (n,) step from each sample to the next [s] (the recording's
    clock); ``fs``: the recording's rate, for the messages; ``rate_from_clock``: the rate was fitted to
    timestamps (then a factor 2 or 1/2 points at the gyro's scale). ``force``: return a ``forced`` result
    instead of raising :class:`UnitsCheckError`.
    """
    gyro = np.asarray(gyro_rad_s, dtype=np.float64)
    accel = np.asarray(accel, dtype=np.float64)
    dt = np.asarray(dt, dtype=np.float64)
    iv, u, bias, gangle = _pairs_problem(gyro, accel, intervals, dt)
    use = np.flatnonzero(gangle >= MIN_PAIR_ANGLE_DEG)
    pairs = [(int(i), int(i) + 1) for i in use]
    if len(use) < MIN_PAIRS:
        return UnitsCheck("not checked", f"{len(use)} pair(s) of consecutive static poses whose gravity directions "
                          f"differ by >= {MIN_PAIR_ANGLE_DEG:g} deg ({len(iv)} poses); at least {MIN_PAIRS} are "
                          "needed (the closure sees no rotation about the vertical)", pairs=pairs,
                          gravity_angle_deg=gangle)
    angles = _closure(gyro, dt, iv, u, bias, use)
    s = best_scale(angles)
    at1, atbest = angles(1.0), angles(s)
    out = UnitsCheck("passed", "", s, pairs=pairs, closure_deg=at1, closure_best_deg=atbest, gravity_angle_deg=gangle)
    summary = (f"{len(use)} informative pairs of static poses close best with the gyro scaled by {s:.4g} "
               f"(closure rms {np.sqrt(np.mean(atbest ** 2)):.3g} deg there, {np.sqrt(np.mean(at1 ** 2)):.3g} deg "
               "at the declared scale)")
    if abs(s - 1.0) <= PASS_TOLERANCE:
        out.reason = summary
        return out
    named = _name(s, rate_from_clock, fs)
    if named is None:
        out.field = "gyro.units"
        out.mistake = (f"no known mislabelling gives a factor {s:.4g} (180/pi, pi/180, 2 or 1/2); a gyro scale off by "
                       f"{100 * abs(s - 1):.3g} % is implausible")
        fix = ("check gyro.units, gyro.scale and sample_rate_hz; if the gyro's scale really is this far off, set "
               "units_check: false")
    else:
        out.field, out.mistake, fix = named
    out.reason = f"{summary}: {out.mistake}"
    if force:
        out.status = "forced"
        return out
    out.status = "refused"
    raise UnitsCheckError(f"{summary} -- {out.mistake}", file=source, field=out.field, fix=fix)
