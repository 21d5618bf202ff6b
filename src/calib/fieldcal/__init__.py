"""Field calibration of real recordings that hold no turntable record.

Without a table the orientations are unknown; what a multi-position session offers is (a) the *norm* of
the specific force at rest, which must equal local gravity, and (b) between two rests, the rotation that
the gyros integrate, which must carry the gravity direction of the first rest into that of the second.
This package implements both (the multi-position idea of IMU-TK, Tedaldi, Pretto & Menegatti, ICRA 2014,
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
* identifiability: SVD of the column-scaled Jacobian (each column divided by its norm), by
  :func:`calib.calibration.identifiability.rank_summary`, the same SVD as the turntable calibration's. For the
  accel it is evaluated on the interval *means* (one row per interval), so that sample noise cannot lend rank
  to orientations that were never visited. Rank = number of singular values above ``rank_rtol`` x the
  largest; the weakest direction is the right singular vector of the smallest one.

Modules: ``results`` (result objects, names, settings keys), ``accelerometer`` (gravity norm), ``intervals``
(which static intervals and samples), ``gyroscope`` (gravity directions), ``ferraris`` (labelled sessions),
``units_check`` (the gyro's declared units and the rate checked by rotation between static poses, before the gyro
fit), ``session`` (a whole recording). What a pose set does not determine: each fit's ``determination``
(:class:`calib.fieldcal.results.Determination`: marginal standard errors against plausibility scales, the
verdicts, the parameters held at nominal). Public API, re-exported here: :func:`fieldcal_recording` (workflow),
:func:`fit_accel_norm`, :func:`fit_gyro_directions`, :func:`fit_ferraris`, :func:`imu_tk_intervals`,
:func:`imu_tk_accel_search`, :func:`mikoff_standstill`, :func:`norm_residual_rms`, and the result classes
:class:`FieldCalResult` and :class:`TriadFit` (whose :meth:`TriadFit.model` is the fit as a
:class:`calib.core.triad.TriadModel`).
"""
from calib.fieldcal.results import (  # noqa: F401
    ACCEL_NAMES,
    BIAS_NAMES,
    DETECTION_KEYS_DETECT,
    DETECTION_KEYS_IMU_TK,
    EVALUATIONS,
    FERRARIS_M_NAMES,
    FieldCalError,
    FieldCalResult,
    GYRO_BIAS_MODES,
    GYRO_KEYS,
    GYRO_NAMES,
    IMU_TK_DEFAULTS,
    MIN_INTERVALS,
    RECOMMENDED_INTERVALS,
    SETTINGS_KEYS,
    TriadFit,
    input_label,
    scale_factor_units,
)
from calib.fieldcal.accelerometer import (  # noqa: F401
    accel_apply,
    accel_jacobian,
    accel_matrix,
    accel_residual,
    ellipsoid_guess,
    fit_accel_norm,
    misalignment_matrix,
    norm_residual_rms,
    range_guess,
)
from calib.fieldcal.intervals import (  # noqa: F401
    imu_tk_accel_search,
    imu_tk_intervals,
    mikoff_standstill,
)
from calib.fieldcal.gyroscope import (  # noqa: F401
    GSENS_NAMES,
    direction_angles_deg,
    direction_check,
    fit_gyro_directions,
    gyro_static_regression,
    integrate_quaternions,
    quats_to_dcm,
)
from calib.fieldcal.ferraris import (  # noqa: F401
    LABEL_PATTERN,
    fit_ferraris,
)
from calib.fieldcal.units_check import (  # noqa: F401
    UnitsCheck,
    UnitsCheckError,
    check_gyro_units,
)
from calib.fieldcal.session import (  # noqa: F401
    fieldcal_recording,
)
