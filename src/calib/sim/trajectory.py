"""Calibration path plan (Liu 2021 §2.2 and §3.3) and the exact true kinematics of the turntable.

Frames
------
* ``n``: local-level navigation frame East-North-Up (ENU).
* ``b``: body frame of the IMU, right-front-up (Liu 2021 §2.1).
* ``C_b^n`` maps body vectors to ENU. A table rotation by angle ``theta`` about a *body* axis ``u``
  right-multiplies the attitude: ``C_b^n(t) = C_b^n(t0) R_u(theta(t))``, with ``R_u`` the active
  right-handed rotation (Rodrigues).

The path
--------
Static positions of Liu 2021 §2.2 (three phases of ``positions_per_phase`` positions ``step_deg`` apart):

* phase 1: body x north, z up at POS1 (so y west); POS k = POS1 rotated by ``(k-1) step`` about body x;
* phase 2: body y north, x up at POS1 (z west); rotations about body y;
* phase 3: body z north, y up at POS1 (x west); rotations about body z.

The phase axis points north throughout its phase. Labels ``P1-POS3`` etc.

Rotation windows of Liu 2021 §3.3 (supplementary gyro path): for each body axis a in x, y, z, for each
rate in ``rotation_rates_deg_s``, a positive then a negative constant-rate rotation of ``revolutions``
whole turns about body axis a held vertical (up). The start attitude of a window makes Liu 2021 eq. (21)
hold literally: for z the body axes are along E, N, U (``omega^b = R_z(wt)^T (0, W cos L, w + W sin L)``);
for x and y the cyclic permutations (x up, y east, z north; y up, z east, x north). Labels
``ROT-z+10`` / ``ROT-z-10``. With ``rotation_axes='vertical+horizontal'`` the same windows follow
about each axis held horizontal pointing north (start attitude = that axis' phase POS1), labels
``ROTH-x+10``.

Transitions (kind ``transition``; segment_index -1 in a recording) move the table between segments
with bounded angular acceleration: a rest-to-rest move by angle D about a fixed body axis is a
trapezoidal rate profile (ramp up in ``t_ramp``, cruise, ramp down in ``t_ramp``) followed by a settle
of ``t_settle`` at rest; within-phase moves turn about the phase axis by ``step_deg``, other moves
(phase changes, repositioning before a rotation window) turn about the eigen-axis of the relative
rotation (the shortest rotation). A rotation window is entered by a constant-acceleration spin-up of
``t_ramp`` (started at an attitude chosen so that the window starts exactly at its nominal attitude)
and left by a spin-down of ``t_ramp`` and a settle. Each transition is a sequence of *primitives*, each
a single-axis motion with constant angular acceleration, so the whole path is a list of
:class:`Segment` primitives with analytic ``theta(t) = rate t + accel t^2 / 2``.

Kinematics (exact, closed form, no integration steps)
----------------------------------------------------
For a table fixed on the rotating Earth at rest (no translation), at a point on the table axes::

    C_b^n(t)    = C_b^n(t_k) R_u(theta(t))                       (Rodrigues, exact)
    omega_nb^b  = u theta'(t)                                     table rate  [rad/s]
    omega_ib^b  = omega_nb^b + C_n^b omega_ie^n                   omega_ie^n = (0, W cos L, W sin L)
    f^b         = C_n^b (0, 0, gamma)                             gamma: WGS-84 normal gravity [m/s^2]

(``omega_en = 0`` at rest; the centripetal and tangential terms of an off-axis point are added by the
``accel_lever_arm`` effect of :mod:`calib.sim.effects`.)

Table angle: the angle [deg] about the current primitive's axis. It restarts at 0 at the start of every
static and rotation segment (so in a rotation window it is ``rate (t - t_start)``, unwrapped, as in Liu 2021
eq. 21) and accumulates across consecutive transition primitives about the same axis (e.g. the
spin-down continues from ``revolutions * 360``); it restarts when the axis changes.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from calib.core import earth
from calib.core.rotations import axis_angle, skew

AXIS_NAMES = ("x", "y", "z")
_EAST = np.array([1.0, 0.0, 0.0])
_NORTH = np.array([0.0, 1.0, 0.0])
_UP = np.array([0.0, 0.0, 1.0])
_WEST = -_EAST
_TINY_ANGLE_DEG = 1e-9


@dataclass
class Segment:
    """One motion primitive of the path: a single-axis motion with constant angular acceleration.

    * ``kind``: ``'static'`` (calibration position), ``'rotation'`` (constant-rate window) or
      ``'transition'`` (motion between them; not a calibration segment).
    * ``label``: ``'P1-POS3'``, ``'ROT-z+10'``, or for transitions ``'P1-POS1>P1-POS2:ramp-up'`` etc.
    * ``axis``: unit rotation axis in the body frame (for static positions: the table axis of the phase).
    * ``rate_deg_s``: signed table rate at the primitive start [deg/s, right-hand rule about ``axis``]
      (0 for static, the window rate for rotations).
    * ``duration_s``: duration [s].
    * ``cbn_start``: C_b^n (body to ENU) at the primitive start.
    * ``accel_deg_s2``: constant angular acceleration [deg/s^2] (transitions only).
    * ``t_start_s``: start time from the session start [s].
    * ``angle0_deg``: table angle at the start (see module doc).
    """

    kind: str
    label: str
    axis: np.ndarray
    rate_deg_s: float
    duration_s: float
    cbn_start: np.ndarray
    accel_deg_s2: float = 0.0
    t_start_s: float = 0.0
    angle0_deg: float = 0.0

    @property
    def t_end_s(self) -> float:
        return self.t_start_s + self.duration_s

    def angle_deg(self, tau):
        """Angle turned [deg] after ``tau`` seconds into the primitive."""
        return self.rate_deg_s * tau + 0.5 * self.accel_deg_s2 * tau * tau

    @property
    def cbn_end(self) -> np.ndarray:
        return self.cbn_start @ axis_angle(self.axis, math.radians(self.angle_deg(self.duration_s)))


def phase_start_attitude(axis: int) -> np.ndarray:
    """C_b^n of POS1 of the phase whose table axis is body ``axis`` (0=x, 1=y, 2=z).

    Body ``axis`` north, the next axis (cyclically) west, the one after up: phase 1 x-N/y-W/z-U,
    phase 2 y-N/z-W/x-U, phase 3 z-N/x-W/y-U (Liu 2021 §2.2).
    """
    c = np.zeros((3, 3))
    c[:, axis] = _NORTH
    c[:, (axis + 1) % 3] = _WEST
    c[:, (axis + 2) % 3] = _UP
    return c


def vertical_rotation_attitude(axis: int) -> np.ndarray:
    """C_b^n at the start of a rotation window about body ``axis`` held up (Liu 2021 eq. 21).

    Body ``axis`` up, the next axis east, the one after north (z: x-E/y-N/z-U, i.e. C = I).
    """
    c = np.zeros((3, 3))
    c[:, axis] = _UP
    c[:, (axis + 1) % 3] = _EAST
    c[:, (axis + 2) % 3] = _NORTH
    return c


def _unit(i: int) -> np.ndarray:
    e = np.zeros(3)
    e[i] = 1.0
    return e


def _fmt_rate(r: float) -> str:
    return f"{'+' if r > 0 else '-'}{abs(r):g}"


class _Builder:
    """Appends primitives with running time, grid-aligned boundaries and table-angle bookkeeping."""

    def __init__(self, grid: float | None, t_ramp: float, t_settle: float, move_rate: float):
        self.grid = grid
        self.t_ramp = self._snap(t_ramp, at_least_one=True)
        self.t_settle = self._snap(t_settle, at_least_one=False)
        self.move_rate = float(move_rate)
        self.segs: list[Segment] = []
        self.t = 0.0

    def _snap(self, d: float, at_least_one: bool = False) -> float:
        """Round a duration to the time grid (if any)."""
        d = float(d)
        if self.grid is None:
            return d
        k = round(d / self.grid)
        if at_least_one:
            k = max(k, 1)
        return k * self.grid

    def add(self, seg: Segment):
        seg.t_start_s = self.t
        if seg.kind == "transition" and self.segs:
            prev = self.segs[-1]
            if np.allclose(prev.axis, seg.axis, atol=1e-12):
                seg.angle0_deg = prev.angle0_deg + prev.angle_deg(prev.duration_s)
        self.segs.append(seg)
        self.t += seg.duration_s

    @property
    def attitude(self) -> np.ndarray:
        return self.segs[-1].cbn_end

    def settle(self, label: str, axis):
        """Rest for t_settle, padded so that the next primitive starts on the time grid."""
        d = self.t_settle
        if self.grid is not None:
            end = self.t + d
            k = math.ceil(end / self.grid - 1e-6)
            d = max(k * self.grid - self.t, 0.0)
        if d > 0:
            self.add(Segment("transition", f"{label}:settle", np.asarray(axis, float), 0.0, d, self.attitude))

    def move(self, label: str, axis, angle_deg: float, settle: bool = True):
        """Rest-to-rest trapezoidal move by ``angle_deg`` about body ``axis``, then settle."""
        axis = np.asarray(axis, dtype=float)
        axis = axis / np.linalg.norm(axis)
        a = abs(float(angle_deg))
        sgn = 1.0 if angle_deg >= 0 else -1.0
        if a > _TINY_ANGLE_DEG:
            tr = self.t_ramp
            t_cruise = max(0.0, (a - self.move_rate * tr) / self.move_rate)
            if self.grid is not None and t_cruise > 0:
                t_cruise = math.ceil(t_cruise / self.grid - 1e-9) * self.grid
            w = a / (tr + t_cruise)  # cruise rate so that the total angle is exactly a
            c0 = self.attitude
            self.add(Segment("transition", f"{label}:ramp-up", axis, 0.0, tr, c0, accel_deg_s2=sgn * w / tr))
            if t_cruise > 0:
                self.add(Segment("transition", f"{label}:cruise", axis, sgn * w, t_cruise, self.attitude))
            self.add(Segment("transition", f"{label}:ramp-down", axis, sgn * w, tr, self.attitude,
                             accel_deg_s2=-sgn * w / tr))
        if settle:
            self.settle(label, axis)

    def move_to(self, label: str, target: np.ndarray, settle: bool = True):
        """Shortest (eigen-axis) move from the current attitude to ``target``."""
        rel = self.attitude.T @ target  # body-frame relative rotation: target = C R
        rv = Rotation.from_matrix(rel).as_rotvec()
        ang = float(np.linalg.norm(rv))
        if math.degrees(ang) <= _TINY_ANGLE_DEG:
            if settle:
                self.settle(label, self.segs[-1].axis)
            return
        self.move(label, rv / ang, math.degrees(ang), settle=settle)


def calibration_plan(step_deg=45.0, positions_per_phase=8, dwell_s=60.0, rotation_rates_deg_s=(10.0, 20.0, 30.0),
                     revolutions=2, rotation_axes="vertical", transition_s=(2.0, 3.0), move_rate_deg_s=20.0,
                     time_grid_s=None) -> list[Segment]:
    """The Liu 2021 calibration path as a list of :class:`Segment` primitives (see module doc).

    Parameters
    ----------
    step_deg : angle between consecutive positions of a phase [deg], right-hand rule about the phase axis.
    positions_per_phase : positions per phase (Liu 2021: 8).
    dwell_s : rest time of each static position [s] (Liu 2021: "around 1 minute").
    rotation_rates_deg_s : magnitudes of the constant table rates of the rotation windows [deg/s]
        (Liu 2021 §3.3: 10, 20, 30); empty for no rotation windows.
    revolutions : whole revolutions per rotation window.
    rotation_axes : ``'vertical'`` or ``'vertical+horizontal'``.
    transition_s : ``(t_ramp, t_settle)`` [s]: duration of every rate ramp (spin-up/down, move
        acceleration/deceleration) and the rest after each move.
    move_rate_deg_s : cruise rate of moves between positions [deg/s] (the ramp acceleration is at most
        ``move_rate_deg_s / t_ramp``).
    time_grid_s : if given (the sample interval), every primitive boundary falls on this grid
        (cruise and settle durations are rounded up; rotation windows keep their whole revolutions and are
        on the grid when ``revolutions * 360 / rate`` is a multiple of it).
    """
    if rotation_axes not in ("vertical", "vertical+horizontal"):
        raise ValueError(f"rotation_axes={rotation_axes!r}: use 'vertical' or 'vertical+horizontal'")
    if positions_per_phase < 1:
        raise ValueError(f"positions_per_phase={positions_per_phase}: need at least 1")
    if dwell_s <= 0:
        raise ValueError(f"dwell_s={dwell_s}: must be positive")
    if int(revolutions) != revolutions or revolutions < 1:
        raise ValueError(f"revolutions={revolutions}: must be a positive whole number")
    if len(transition_s) != 2 or transition_s[0] <= 0 or transition_s[1] < 0:
        raise ValueError(f"transition_s={transition_s}: need [t_ramp > 0, t_settle >= 0] seconds")
    if move_rate_deg_s <= 0:
        raise ValueError(f"move_rate_deg_s={move_rate_deg_s}: must be positive")
    rates = [float(r) for r in rotation_rates_deg_s]
    if any(r <= 0 for r in rates):
        raise ValueError(f"rotation_rates_deg_s={rates}: give positive magnitudes; both signs are run")
    b = _Builder(time_grid_s, transition_s[0], transition_s[1], move_rate_deg_s)
    dwell = b._snap(dwell_s, at_least_one=True)
    prev_label = None
    for ph in range(3):
        u = _unit(ph)
        c1 = phase_start_attitude(ph)
        for k in range(positions_per_phase):
            label = f"P{ph + 1}-POS{k + 1}"
            target = c1 @ axis_angle(u, math.radians(k * step_deg))
            if prev_label is not None:
                if k == 0:
                    b.move_to(f"{prev_label}>{label}", target)
                else:
                    b.move(f"{prev_label}>{label}", u, step_deg)
            b.add(Segment("static", label, u, 0.0, dwell, target))
            prev_label = label
    windows = [("ROT", vertical_rotation_attitude)]
    if rotation_axes == "vertical+horizontal":
        windows.append(("ROTH", phase_start_attitude))
    for prefix, start_att in windows:
        for ax in range(3):
            u = _unit(ax)
            c0 = start_att(ax)
            for r in rates:
                for sgn in (1.0, -1.0):
                    w = sgn * r
                    label = f"{prefix}-{AXIS_NAMES[ax]}{_fmt_rate(w)}"
                    tr = b.t_ramp
                    th_up = w * tr / 2.0
                    pre = c0 @ axis_angle(u, math.radians(-th_up))
                    b.move_to(f"{prev_label}>{label}", pre)
                    b.add(Segment("transition", f">{label}:spin-up", u, 0.0, tr, b.attitude, accel_deg_s2=w / tr))
                    dur = revolutions * 360.0 / r
                    b.add(Segment("rotation", label, u, w, dur, c0))
                    b.add(Segment("transition", f"{label}>:spin-down", u, w, tr, b.attitude, accel_deg_s2=-w / tr))
                    b.settle(f"{label}>", u)
                    prev_label = label
    if not b.segs:
        raise ValueError("calibration_plan: empty path")
    return b.segs


def recorded_segments(plan) -> list[Segment]:
    """The static and rotation segments of a plan (the recording's segment table), in order."""
    return [s for s in plan if s.kind != "transition"]


def planned_nominal_attitudes(plan=None, **plan_kwargs) -> np.ndarray:
    """Nominal C_b^n (body to ENU) at the start of every static/rotation segment, shape (n, 3, 3).

    Pass a plan from :func:`calibration_plan` or its keyword arguments.
    """
    if plan is None:
        plan = calibration_plan(**plan_kwargs)
    return np.array([s.cbn_start for s in recorded_segments(plan)])


def segment_table(plan) -> dict:
    """Per-segment arrays for :func:`calib.io.recording.make_dataset` (``segments=``)."""
    segs = recorded_segments(plan)
    return {
        "segment_kind": [s.kind for s in segs],
        "segment_label": [s.label for s in segs],
        "rotation_axis": np.array([s.axis for s in segs]),
        "rotation_rate": np.array([s.rate_deg_s for s in segs]),
        "nominal_attitude": np.array([s.cbn_start for s in segs]),
    }


def plan_duration(plan) -> float:
    """Total duration of a plan [s]."""
    return plan[-1].t_end_s


def sample_segment_index(plan, n_samples: int, sample_rate_hz: float, time_shift_s: float = 0.0) -> np.ndarray:
    """Segment index (into :func:`recorded_segments`) of every sample, -1 for transitions.

    Sample k covers ``[k/fs, (k+1)/fs)`` of the table record (shifted by ``time_shift_s``); it belongs to a
    segment when that interval lies inside the segment (boundaries within 1e-6 sample count as on it).
    """
    fs = float(sample_rate_hz)
    idx = np.full(n_samples, -1, dtype=np.int32)
    for j, s in enumerate(recorded_segments(plan)):
        a = (s.t_start_s - time_shift_s) * fs
        e = (s.t_end_s - time_shift_s) * fs
        k0 = max(math.ceil(a - 1e-6), 0)
        k1 = min(math.floor(e + 1e-6), n_samples)  # exclusive: sample k1-1 ends at k1/fs <= e
        if k1 > k0:
            idx[k0:k1] = j
    return idx


@dataclass
class Kinematics:
    """True kinematics at times ``t`` (all body-frame vectors; shapes (n, 3) or (n, 3, 3))."""

    t: np.ndarray
    cbn: np.ndarray          # C_b^n, body to ENU
    w_ib_b: np.ndarray       # omega_ib^b [rad/s] = table rate + C_n^b omega_ie^n
    f_b: np.ndarray          # specific force at the table-axis point [m/s^2]
    w_nb_b: np.ndarray       # table rate omega_nb^b [rad/s]
    dw_nb_b: np.ndarray      # table angular acceleration [rad/s^2]
    table_angle_deg: np.ndarray
    primitive: np.ndarray    # index of the plan primitive of each time
    extra: dict = field(default_factory=dict)


class Trajectory:
    """Vectorised evaluation of the exact kinematics of a plan (see module doc).

    Times before 0 hold the initial attitude at rest and times after the end the final one.
    """

    def __init__(self, plan):
        self.plan = list(plan)
        n = len(self.plan)
        self.t0 = np.array([s.t_start_s for s in self.plan])
        self.dur = np.array([s.duration_s for s in self.plan])
        self.rate = np.radians([s.rate_deg_s for s in self.plan])
        self.acc = np.radians([s.accel_deg_s2 for s in self.plan])
        self.ang0 = np.array([s.angle0_deg for s in self.plan])
        self.axis = np.array([s.axis for s in self.plan], dtype=float)
        self.A0 = np.empty((n, 3, 3))
        self.A1 = np.empty((n, 3, 3))
        self.A2 = np.empty((n, 3, 3))
        for i, s in enumerate(self.plan):
            k = skew(self.axis[i])
            self.A0[i] = s.cbn_start
            self.A1[i] = s.cbn_start @ k
            self.A2[i] = s.cbn_start @ k @ k
        self.duration_s = float(self.t0[-1] + self.dur[-1])

    def kinematics(self, t, lat_rad: float, height_m: float = 0.0, gravity_m_s2: float | None = None) -> Kinematics:
        """True C_b^n, omega_ib^b, f^b, table rate/acceleration and table angle at times ``t`` [s].

        ``lat_rad`` geodetic latitude [rad]; ``gravity_m_s2`` the magnitude of local gravity (default
        WGS-84 normal gravity at ``lat_rad``, ``height_m``).
        """
        t = np.asarray(t, dtype=float).reshape(-1)
        # a time on a primitive boundary (to rounding of the accumulated start times) belongs to the new
        # primitive: the kinematics are continuous there, but the table angle restarts with each segment
        idx = np.clip(np.searchsorted(self.t0, t + 1e-9, side="right") - 1, 0, len(self.plan) - 1)
        tau = t - self.t0[idx]
        moving = (tau >= 0) & (tau <= self.dur[idx])
        tau = np.clip(tau, 0.0, self.dur[idx])
        rate0, acc = self.rate[idx], self.acc[idx]
        theta = rate0 * tau + 0.5 * acc * tau * tau
        thdot = np.where(moving, rate0 + acc * tau, 0.0)
        thddot = np.where(moving, acc, 0.0)
        s, c = np.sin(theta), np.cos(theta)
        cbn = self.A0[idx] + s[:, None, None] * self.A1[idx] + (1.0 - c)[:, None, None] * self.A2[idx]
        u = self.axis[idx]
        w_nb = u * thdot[:, None]
        dw_nb = u * thddot[:, None]
        w_ie_n = earth.earth_rate_enu(lat_rad)
        # C_n^b v = (C_b^n)^T v  -> einsum over the row index
        w_ib = w_nb + np.einsum("kij,i->kj", cbn, w_ie_n)
        g = float(earth.normal_gravity(lat_rad, height_m)) if gravity_m_s2 is None else float(gravity_m_s2)
        f_b = g * cbn[:, 2, :]  # C_n^b (0, 0, g) = g * third row of C_b^n
        angle = self.ang0[idx] + np.degrees(theta)
        return Kinematics(t, cbn, w_ib, f_b, w_nb, dw_nb, angle, idx)
