"""Sensor error model of a triad (Liu 2021 eqs. 1-4) and its parameter vector.

    N = K E x + b                                            (Liu 2021 eqs. 1 and 3)

* ``x`` the true input in the body frame (specific force or angular rate), in the triad's *input unit*;
* ``K = diag(Kx, Ky, Kz)`` scale factors [output unit per input unit];
* ``E`` installation-error matrix with unit diagonal (Liu 2021 eq. 2/4): rows are the sensitive axes
  of the x, y, z sensors expressed in the body frame, to first order;
* ``b`` biases [output unit].

Parameter vector order (Liu 2021 eqs. 8 and 19)::

    [Kx, Ky, Kz, Exy, Exz, Eyx, Eyz, Ezx, Ezy, bx, by, bz]

Units of the synthetic unit (Liu 2021 does not state them; this is the project's documented reading):

* accelerometers: input in standard g (9.80665 m/s^2), output in ``count s-1`` (the pulse rate of a
  quantised velocity-increment channel), so ``Ka ~ 13942 count s-1 per g`` and ``ba ~ -207 count s-1``
  (-0.0148 g);
* gyros: input in deg/h, output in ``count s-1``, so ``Kg ~ 7922 count s-1 per deg/h`` and a bias of
  -208 count s-1 is -0.026 deg/h, a plausible navigation-grade FOG.

With these units the bounds of Liu 2021 Tables 1 and 3 contain the true values.

Applying a calibration to raw samples is the inverse model, :class:`TriadCorrection` (eq. 5 there): one type and
one ``apply`` for the turntable calibration (:mod:`calib.calibration.fit`), the field calibration
(:mod:`calib.fieldcal`), the navigation (:mod:`calib.nav.navigation`), ``calib apply`` / ``calib export``
(:mod:`calib.io.export_formats`) and an import's declared per-axis scale and sign (:mod:`calib.ingest.common`).
:meth:`TriadModel.inverse` is the exact inverse of the forward model, which the simulation uses to find the input
of a given output.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from calib.core.earth import STANDARD_GRAVITY

#: parameters of the identified accelerometer norm model (Liu 2021 eq. 7 in its 9-parameter lower-triangular form)
NORM_PARAMETERS = 9
#: static poses that leave a degree of freedom to test that model: ``calib fieldcal`` (which calibrates from
#: NORM_PARAMETERS but then says it has no redundancy) and ``calib diagnose`` (which needs this many) agree on it
MIN_POSES_TO_TEST = NORM_PARAMETERS + 1
PARAM_NAMES = ("Kx", "Ky", "Kz", "Exy", "Exz", "Eyx", "Eyz", "Ezx", "Ezy", "bx", "by", "bz")
#: positions of the off-diagonal installation errors inside E, in parameter order
OFFDIAG = ((0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1))

#: input units of the two triads of the synthetic unit, with the factor to SI
INPUT_UNITS = {"accel": ("g", STANDARD_GRAVITY), "gyro": ("deg h-1", math.pi / 180.0 / 3600.0)}


@dataclass
class TriadModel:
    """Linear triad model N = K E x + b. ``input_unit``/``output_unit`` are strings of the recording format."""

    K: np.ndarray
    E: np.ndarray
    b: np.ndarray
    input_unit: str = "g"
    output_unit: str = "count s-1"
    extra: dict = field(default_factory=dict)

    @property
    def KE(self) -> np.ndarray:
        return np.diag(self.K) @ self.E

    def forward(self, x):
        """Output N for inputs ``x`` (..., 3) in the input unit (base model only)."""
        return np.asarray(x) @ self.KE.T + self.b

    def inverse(self, n):
        """Input x = (K E)^-1 (N - b) for outputs ``n`` (..., 3), by solving the linear system (the simulation's
        inverse; a calibration applied to samples is a :class:`TriadCorrection`)."""
        return np.linalg.solve(self.KE, (np.asarray(n) - self.b).T).T

    def to_vector(self) -> np.ndarray:
        return np.concatenate([self.K, [self.E[i, j] for i, j in OFFDIAG], self.b])

    @classmethod
    def from_KE(cls, KE, b, input_unit="g", output_unit="count s-1", extra=None) -> "TriadModel":
        """The model of a full matrix K E (non-zero diagonal): K = diag(K E), E = diag(K)^-1 K E."""
        KE = np.asarray(KE, dtype=float)
        K = np.diag(KE).copy()
        if np.any(K == 0):
            raise ValueError("K E has a zero on its diagonal: not a triad model (a sensor axis sees nothing)")
        return cls(K, KE / K[:, None], np.asarray(b, dtype=float).copy(), input_unit, output_unit, dict(extra or {}))

    @classmethod
    def from_vector(cls, theta, input_unit="g", output_unit="count s-1") -> "TriadModel":
        theta = np.asarray(theta, dtype=float)
        E = np.eye(3)
        for k, (i, j) in enumerate(OFFDIAG):
            E[i, j] = theta[3 + k]
        return cls(theta[0:3].copy(), E, theta[9:12].copy(), input_unit, output_unit)


SAMPLE_KINDS = ("rate", "increment")


@dataclass(frozen=True, eq=False)
class TriadCorrection:
    """The inverse model of one triad: the correction of its raw samples, the one way calib applies a calibration.

        N = f r                 (``sample_kind`` rate)
        N = f r / dt            (``sample_kind`` increment, dt the sample interval [s])
        x = A (N - beta - G a)                                                              (5)

    * ``r`` raw samples (..., 3) in the recording's unit; ``f`` ``factor`` (scalar, or one per axis) from it to the
      *reading unit* ``reading_unit`` in which ``bias`` is stated (``N``: the rate reading);
    * ``A`` ``matrix`` (3x3) [``output_unit`` per reading unit]: scale and misalignment; None for a triad whose
      axes are not coupled (a declared per-axis scale and sign): x = N - beta, each axis on its own, so that a
      NaN on one axis stays on that axis;
    * ``beta`` ``bias`` (3,) [reading unit]; None: no offset;
    * ``G`` ``g_sensitivity`` (3x3, gyros) [reading unit per m s-2]: the offset per unit calibrated specific force
      ``a`` [m s-2] of the same samples; None: none;
    * ``x`` in ``output_unit``, in ``frame``.

    Of the forward model N = K E x + b (:class:`TriadModel`, Liu 2021 eqs. 1-4) with x in ``output_unit`` times
    ``s`` and N = ``f_r`` times a rate reading: A = s (K E)^-1 f_r, beta = b / f_r, G = G_N / f_r
    (:meth:`from_KE`, :meth:`from_model`, :meth:`from_vector`). A field calibration estimates A and beta directly
    (lower-triangular or Ferraris form): construct the correction from them.
    """

    sensor: str
    matrix: np.ndarray | None
    bias: np.ndarray | None
    reading_unit: str
    output_unit: str
    factor: float | np.ndarray = 1.0
    frame: str = ""
    g_sensitivity: np.ndarray | None = None

    @classmethod
    def from_KE(cls, sensor, KE, b, reading_unit, output_unit, *, output_factor=1.0, reading_factor=1.0,
                g_sensitivity=None, frame="") -> "TriadCorrection":
        """The correction of the forward model N = K E x + b: A = ``output_factor`` (K E)^-1 ``reading_factor``,
        beta = b / ``reading_factor``, G = ``g_sensitivity`` / ``reading_factor``. ``output_factor``: from the
        model's input unit to ``output_unit``; ``reading_factor``: from the rate reading (``reading_unit``) to the
        model's output unit (N = reading_factor x reading)."""
        A = output_factor * np.linalg.inv(np.asarray(KE, dtype=float)) * reading_factor
        G = None if g_sensitivity is None else np.asarray(g_sensitivity, dtype=float) / reading_factor
        return cls(sensor, A, np.asarray(b, dtype=float) / reading_factor, reading_unit, output_unit, frame=frame,
                   g_sensitivity=G)

    @classmethod
    def from_model(cls, model: "TriadModel", sensor, *, output_unit=None, output_factor=1.0, reading_factor=1.0,
                   reading_unit=None, g_sensitivity=None, frame="") -> "TriadCorrection":
        """The correction of a :class:`TriadModel` (:meth:`from_KE`); by default to the model's input unit, from
        readings in its output unit."""
        return cls.from_KE(sensor, model.KE, model.b, model.output_unit if reading_unit is None else reading_unit,
                           model.input_unit if output_unit is None else output_unit, output_factor=output_factor,
                           reading_factor=reading_factor, g_sensitivity=g_sensitivity, frame=frame)

    @classmethod
    def from_vector(cls, theta, sensor, input_unit, output_unit="count s-1", **kw) -> "TriadCorrection":
        """The correction of Liu's 12-parameter vector ``[Kx Ky Kz Exy Exz Eyx Eyz Ezx Ezy bx by bz]`` (eq. 8)."""
        return cls.from_model(TriadModel.from_vector(theta, input_unit, output_unit), sensor, **kw)

    def model(self) -> "TriadModel":
        """The forward model N = K E x + b of this correction (x in ``output_unit``, N in ``reading_unit``): K E = A^-1
        (the factor and the g-sensitivity are not part of it)."""
        if self.matrix is None:
            raise ValueError(f"{self.sensor}: a correction without a matrix (per-axis scale) has no triad model")
        b = np.zeros(3) if self.bias is None else self.bias
        return TriadModel.from_KE(np.linalg.inv(self.matrix), b, input_unit=self.output_unit,
                                  output_unit=self.reading_unit)

    def reading(self, raw, sample_kind: str = "rate", dt: float | None = None) -> np.ndarray:
        """The rate reading N = f r (rate samples) or f r / dt (increment samples) of raw samples ``r``."""
        N = np.ascontiguousarray(raw, dtype=np.float64) * self.factor
        if sample_kind == "increment":
            if not dt:
                raise ValueError("increment samples need dt [s] to become a rate")
            return N / dt
        if sample_kind != "rate":
            raise ValueError(f"sample_kind must be 'rate' or 'increment', got {sample_kind!r}")
        return N

    def correct(self, reading, accel=None) -> np.ndarray:
        """x = A (N - beta - G a) of rate readings N (..., 3) in ``reading_unit``; ``accel`` the calibrated specific
        force [m s-2] of the same samples (needed when ``g_sensitivity`` is set)."""
        x = reading if self.bias is None else reading - self.bias
        if self.g_sensitivity is not None:
            if accel is None:
                raise ValueError(f"the {self.sensor} correction is g-sensitive: give accel, the calibrated specific "
                                 "force [m s-2] of the same samples")
            x = x - np.asarray(accel, dtype=float) @ self.g_sensitivity.T
        return x if self.matrix is None else x @ self.matrix.T

    def apply(self, raw, *, sample_kind: str = "rate", dt: float | None = None, accel=None) -> np.ndarray:
        """Corrected samples x (..., 3) [``output_unit``, ``frame``] of raw samples (eq. 5)."""
        return self.correct(self.reading(raw, sample_kind, dt), accel)


#: "Separate calibration results" of Liu 2021 Table 1 (accelerometers) and Table 3 (gyros):
#: scale factors, biases, and the two installation-error columns (row i holds E_i,j for j != i in order).
LIU2021_ACCEL = {
    "K": [13942.35422951, 13345.72485877, 13062.44709817],
    "b": [-206.59251066, 87.24553607, 333.71033323],
    "E": [[0.00336420, 0.00191168], [0.00271530, -0.00204019], [-0.00739421, -0.00044851]],
    "lower": {"K": 13000.0, "b": -400.0, "E": -0.01},
    "upper": {"K": 14000.0, "b": 400.0, "E": 0.01},
}
LIU2021_GYRO = {
    "K": [7921.74760617, 7911.54386049, 7924.57007346],
    "b": [-208.33680363, -33.24299533, -54.56475774],
    "E": [[-0.00489132, 0.00096090], [0.00058152, 0.00018519], [0.00449350, 0.00137873]],
    "lower": {"K": 7800.0, "b": -500.0, "E": -0.01},
    "upper": {"K": 8000.0, "b": 100.0, "E": 0.01},
}


def liu2021_model(sensor: str) -> TriadModel:
    """The Liu 2021 'separate calibration results' as a :class:`TriadModel` (the default synthetic truth)."""
    t = LIU2021_ACCEL if sensor == "accel" else LIU2021_GYRO
    E = np.eye(3)
    flat = [v for row in t["E"] for v in row]
    for k, (i, j) in enumerate(OFFDIAG):
        E[i, j] = flat[k]
    return TriadModel(np.array(t["K"]), E, np.array(t["b"]), INPUT_UNITS[sensor][0], "count s-1")


def liu2021_bounds(sensor: str):
    """Lower and upper bounds of Liu 2021 Table 1 (accel) or Table 3 (gyro) in parameter order."""
    t = LIU2021_ACCEL if sensor == "accel" else LIU2021_GYRO
    lo = [t["lower"]["K"]] * 3 + [t["lower"]["E"]] * 6 + [t["lower"]["b"]] * 3
    hi = [t["upper"]["K"]] * 3 + [t["upper"]["E"]] * 6 + [t["upper"]["b"]] * 3
    return np.array(lo), np.array(hi)
