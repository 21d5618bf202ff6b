"""Calibration of an accelerometer or gyro triad from segment means (Liu 2021), with standard errors.

Model (Liu 2021 eqs. 1-4): ``N = K E x + b``; N rate reading [output unit; count s-1 for the synthetic unit:
counts per sample / dt], x input in the body frame [input unit: g for accelerometers, deg/h for gyros].
Applying a result to raw output: ``N = counts / dt`` (increment channels) or the sample itself (rate
channels), then ``x = (K E)^-1 (N - b)`` (:meth:`CalibrationResult.apply`, the triad's
:class:`calib.core.triad.TriadCorrection`).

The methods
-----------
Accelerometer

* :func:`separate_accel` — classical (separate) calibration, the gold-standard baseline: vector observations
  ``N_m = K E f_m + b`` with ``f_m = C_n^b (0, 0, g)`` from the nominal attitudes of the segment table;
  linear least squares for the 12 parameters. Frame: the body frame as realised by the table attitudes.
* :func:`norm_calibration` (``form='tri9'``, default for main results) — Liu 2021 eq. 7 minimised by IDE
  (eq. 18) + least-squares polish, in the lower-triangular parameterisation that the norm *does* identify
  (rank 9 of 9): ``Exy = Exz = Eyz = 0``. Frame: the *triad frame* (x along the x sensor's sensitive axis, y
  in the plane of the x and y sensitive axes); it differs from the body frame by a small rotation the norm
  cannot observe. The paper's 12-parameter form is recovered only up to that rotation
  (:meth:`CalibrationResult.paper_form`, chosen closest to a reference).
* :func:`norm_calibration` (``form='paper12'``) — the paper's form: rank 9 of 12 (a rotation of the whole
  triad leaves every norm unchanged). The solution is one point of a 3-dimensional valley; standard errors
  of the individual installation errors are not defined (reported as NaN), those of K and b are, and the
  identified combination ``(K E)(K E)^T`` (``derived['gram']``) is reported with its covariance.

Gyro

* :func:`gyro_components` (default) — component form of Liu 2021 eq. 25: ``(N+ - N-) / (2 omega) = K E a``
  (a column of K E per rotation axis; linear, rank 9 with rotations about three axes), then the biases from
  the pair means ``(N+ + N-)/2`` and/or the static positions with the known Earth-rate input
  (``bias_from='both'|'pairs'|'static'``), or from the static norm with K E held (``'norm'``, §3.3).
* :func:`separate_gyro` — classical joint linear least squares on all static and rotation means with their
  known inputs (table rate + Earth rate).
* :func:`norm_calibration` on gyro static means — L_g of eq. 7 (Liu 2021 §3.2): Earth rate is the only
  input, so the signal is ~15 deg/h against the noise; the paper reports that this fails.
* :func:`gyro_dynamic` — Liu 2021 §3.3: L_gm of eq. 26 by IDE (+ polish) for K and E, then the biases from
  the static norm (eq. 7) with K and E held. L_gm constrains only the three column norms of K E (Jacobian
  rank 3 of 9), so the six installation errors it returns are arbitrary within the bounds; this is reported.

Standard errors: from the residual Jacobian at the solution and the sigma of every mean estimated from the
data (Allan deviation at tau = segment duration, ``allan.py``): for the unweighted eq. 7 the sandwich
``C = J^+ diag(sigma_r^2) J^+T`` (pseudo-inverse in bound-scaled coordinates, so rank-deficient forms give the
minimum-norm gauge), for weighted / linear fits ``(J^T W J)^-1`` (:mod:`calib.calibration.covariance`). The
covariance is *not* rescaled by the reduced chi-square; ``chi2`` and ``dof`` are reported so the user can judge
the sigma model.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from calib.calibration import covariance as cv
from calib.calibration import identifiability as idf
from calib.calibration import linear as lin
from calib.calibration import objectives as ob
from calib.calibration import optimizers as opt
from calib.signal.segments import RotationMeans, RotationPairs, SegmentError, StaticMeans, require_positions
from calib.core.triad import PARAM_NAMES, TriadCorrection, TriadModel, liu2021_bounds

FRAME_BODY = "body frame (as realised by the nominal table attitudes; Liu 2021: right-front-up)"
FRAME_TRIAD = ("triad frame: x along the x sensor's sensitive axis, y in the plane of the x and y sensitive "
               "axes, z completing a right-handed orthonormal frame; it differs from the body frame by a small "
               "rotation that the norm cannot observe")
FRAME_UNDETERMINED = ("body frame up to an unidentified rotation of the triad (the norm does not determine "
                      "the triad's orientation)")


@dataclass
class CalibrationResult:
    """One identified triad model N = K E x + b with its uncertainty.

    ``x`` parameters of ``form`` (names ``names``), ``cov`` their covariance, ``KE``/``b`` the model to apply,
    ``frame`` the frame of the calibrated output, units of input / output, the objective value ``L``
    (eq. 7 / eq. 26 as named in ``objective``), chi-square and degrees of freedom, the numerical ``rank``,
    ``identifiability`` report, parameters found on a search bound, notes, the optimiser's result.
    """

    sensor: str
    method: str
    form: str
    names: tuple
    x: np.ndarray
    cov: np.ndarray
    KE: np.ndarray
    b: np.ndarray
    input_unit: str
    output_unit: str
    frame: str
    objective: str = ""
    L: float = math.nan
    chi2: float = math.nan
    dof: int = 0
    rank: int = 0
    identifiability: idf.IdentifiabilityReport | None = None
    on_bound: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    optimizer: opt.Result | None = None
    derived: dict = field(default_factory=dict)
    undetermined: list = field(default_factory=list)

    @property
    def se(self) -> np.ndarray:
        """Standard errors; NaN for parameters the data do not determine individually."""
        s = np.sqrt(np.clip(np.diag(self.cov), 0.0, None))
        for n in self.undetermined:
            s[self.names.index(n)] = np.nan
        return s

    @property
    def chi2_red(self) -> float:
        return self.chi2 / self.dof if self.dof > 0 else math.nan

    def paper_vector(self) -> np.ndarray:
        """[Kx Ky Kz Exy Exz Eyx Eyz Ezx Ezy bx by bz] (Liu 2021 eq. 8) of the model as identified (in its frame)."""
        return ob.paper_vector(self.KE, self.b)

    def paper_form(self, reference=None):
        """The paper's 12-vector, choosing the unidentified rotation (norm forms) so that K E is closest to
        ``reference`` (3x3, e.g. a separate calibration's K E; default diag(K): no preferred rotation).
        For fully identified methods this is :meth:`paper_vector`. Returns (vector (12,), rotation R)."""
        if self.form not in ("tri9", "paper12") or self.method.startswith("separate"):
            return self.paper_vector(), np.eye(3)
        ref = np.diag(np.diag(self.KE)) if reference is None else np.asarray(reference, dtype=float)
        R, M = ob.align_to_reference(self.KE, ref)
        return ob.paper_vector(M, self.b), R

    def model(self) -> TriadModel:
        """The identified model as the one triad model of :mod:`calib.core.triad` (K = diag(K E), unit-diagonal E)."""
        return TriadModel.from_KE(self.KE, self.b, self.input_unit, self.output_unit)

    @property
    def how_to_apply(self) -> str:
        short = self.frame.split(":")[0].split(" (")[0]
        return (f"N [{self.output_unit}] = counts / dt for increment channels (the sample itself for rate "
                f"channels); x [{self.input_unit}, {short}] = (K E)^-1 (N - b)")

    def correction(self) -> TriadCorrection:
        """The identified model's correction (:class:`calib.core.triad.TriadCorrection`): x = (K E)^-1 (N - b),
        in ``input_unit`` and :attr:`frame`, from rate readings N in ``output_unit``."""
        return TriadCorrection.from_KE(self.sensor, self.KE, self.b, self.output_unit, self.input_unit,
                                       frame=self.frame)

    def apply(self, raw, *, sample_kind: str = "rate", dt: float | None = None) -> np.ndarray:
        """Calibrated input (n, 3) [input unit] from raw output (n, 3): x = (K E)^-1 (N - b), N = raw (rate
        samples) or raw / dt (increment samples)."""
        return self.correction().apply(raw, sample_kind=sample_kind, dt=dt)

    def to_dict(self) -> dict:
        se = self.se
        return {
            "sensor": self.sensor, "method": self.method, "form": self.form, "frame": self.frame,
            "input_unit": self.input_unit, "output_unit": self.output_unit,
            "parameters": {n: float(v) for n, v in zip(self.names, self.x)},
            "standard_errors": {n: (None if not np.isfinite(s) else float(s)) for n, s in zip(self.names, se)},
            "covariance": self.cov.tolist(),
            "KE": self.KE.tolist(), "b": self.b.tolist(),
            "paper_vector": dict(zip(PARAM_NAMES, map(float, self.paper_vector()))),
            "objective": self.objective, "L": float(self.L), "chi2": float(self.chi2), "dof": int(self.dof),
            "rank": int(self.rank), "n_params": len(self.names), "undetermined": list(self.undetermined),
            "null_space": [] if self.identifiability is None else list(self.identifiability.descriptions),
            "on_bound": list(self.on_bound), "notes": list(self.notes), "how_to_apply": self.how_to_apply,
        }

    def summary(self) -> str:
        lines = [f"{self.sensor} calibration, {self.method} (form {self.form}), frame: {self.frame}",
                 f"units: input {self.input_unit}, output {self.output_unit}; {self.how_to_apply}"]
        for n, v, s in zip(self.names, self.x, self.se):
            lines.append(f"  {n:4s} = {v:+.10g}  +- {s:.3g}")
        lines.append(f"{self.objective} = {self.L:.6g}; chi2 = {self.chi2:.4g} on {self.dof} dof; "
                     f"rank {self.rank} of {len(self.names)}")
        lines += [f"note: {n}" for n in self.notes]
        return "\n".join(lines)


# ---------------------------------------------------------------------------------------------------------
# search bounds
# ---------------------------------------------------------------------------------------------------------
def default_bounds(sensor, output_unit, form_name, bounds):
    """(lower, upper) of ``form_name``: ``bounds`` if given, else Liu 2021 Tables 1/3 (count outputs only)."""
    if bounds is not None:
        lo, hi = opt.parse_bounds(bounds)
        n = len(ob.FORM_NAMES[form_name])
        if lo.size == 12 and n != 12:
            idx = idf.form_indices(form_name)
            lo, hi = lo[idx], hi[idx]
        if lo.size != n:
            raise ValueError(f"bounds have {lo.size} components, form {form_name!r} has {n} (or give all 12)")
        return lo, hi
    if not str(output_unit).startswith("count"):
        raise ValueError(f"{sensor}: output in {output_unit!r}: the default search bounds (Liu 2021 Tables 1/3) "
                         "are for the synthetic unit's count outputs; give bounds=(lower, upper) for this sensor")
    lo, hi = liu2021_bounds(sensor)
    idx = idf.form_indices(form_name)
    lo, hi = lo[idx].copy(), hi[idx].copy()
    if form_name == "tri9":
        # the lower-triangular gauge folds the rotation into Eyx, Ezx, Ezy (to first order Eyx + Exy, ...):
        # twice the paper's installation-error range
        lo[3:6] *= 2.0
        hi[3:6] *= 2.0
    return lo, hi


def _report_bounds(names, x, lo, hi, notes, rtol=1e-4):
    hits = opt.bound_hits(x, lo, hi, rtol)
    out = [names[j] for j in hits]
    if out:
        msg = ("parameter(s) on a search bound: " + ", ".join(
            f"{names[j]} = {x[j]:.6g} (bounds {lo[j]:.6g} .. {hi[j]:.6g})" for j in hits)
            + " - the optimum probably lies outside the bounds; widen them")
        notes.append(msg)   # no warning per run: a study makes many exploratory runs with small budgets; the
        # result carries it (on_bound, notes) and the calibration a study writes is checked (exit 3) on it
    return out


# ---------------------------------------------------------------------------------------------------------
# classical (separate) calibration
# ---------------------------------------------------------------------------------------------------------
def separate_accel(static: StaticMeans) -> CalibrationResult:
    """Classical multi-position calibration: N_m = K E f_m + b with f_m = C_n^b (0, 0, g) from the nominal
    attitudes, weighted linear least squares per axis (12 parameters), delta-method covariance for K, E."""
    require_positions(static, 5, "the separate (vector) calibration of 12 parameters")
    x_in = static.true_inputs()
    try:
        M, b, cov_lin, chi2 = lin.vector_solve(static.means, x_in, static.sigma)
    except ValueError as exc:
        raise SegmentError(f"{static.source or static.sensor}: {exc}") from exc
    return _linear_result(static.sensor, "separate (vector LS)", M, b, cov_lin, chi2.sum(),
                          3 * (static.n - 4), static, notes=[])


def separate_gyro(static: StaticMeans, rotations: RotationMeans | None = None) -> CalibrationResult:
    """Classical gyro calibration: joint weighted linear least squares N_k = K E w_k + b on all static means
    (w = Earth rate in the body frame) and whole-revolution rotation means (w = table rate + Earth rate along
    the axis). Static positions alone see only Earth rate (weak); rotations make it well conditioned."""
    N = [static.means]
    W = [static.true_inputs()]
    S = [static.sigma]
    if rotations is not None:
        N.append(rotations.means)
        W.append(rotations.mean_inputs())
        S.append(rotations.sigma)
    N, W, S = np.concatenate(N), np.concatenate(W), np.concatenate(S)
    if N.shape[0] < 5:
        raise SegmentError(f"separate gyro calibration needs at least 5 segments (static + rotation), "
                           f"found {N.shape[0]}")
    M, b, cov_lin, chi2 = lin.vector_solve(N, W, S)
    notes = [] if rotations is not None else ["static positions only: Earth rate is the only input (weak)"]
    return _linear_result(static.sensor, "separate (vector LS)", M, b, cov_lin, chi2.sum(), 3 * (N.shape[0] - 4),
                          static, notes=notes)


def _linear_result(sensor, method, M, b, cov_lin, chi2, dof, static, notes, frame=FRAME_BODY, objective_L=True,
                   units=None):
    theta = ob.paper_vector(M, b)
    cov = cv.paper_cov(M, cov_lin)
    L = math.nan
    if objective_L and isinstance(static, StaticMeans):
        L = ob.NormObjective(static.means, static.reference).eq7(theta)
    iu, ou = units if units is not None else (static.input_unit, static.output_unit)
    return CalibrationResult(sensor=sensor, method=method, form="paper12", names=PARAM_NAMES, x=theta, cov=cov,
                             KE=M, b=b, input_unit=iu, output_unit=ou, frame=frame,
                             objective="L (eq. 7) at the solution", L=L, chi2=float(chi2), dof=int(dof), rank=12,
                             notes=notes)


# ---------------------------------------------------------------------------------------------------------
# norm calibration (Liu 2021 eq. 7)
# ---------------------------------------------------------------------------------------------------------
def norm_calibration(static: StaticMeans, *, form: str = "tri9", method: str = "ide_lsq", rng=None, seed: int = 0,
                     budget=(60, 1200), bounds=None, weighted: bool = False, KE=None, cov_means=None,
                     **opts) -> CalibrationResult:
    """Norm-observed calibration of one triad from its static means: minimise L_a / L_g (Liu 2021 eq. 7).

    form: 'tri9' (default; identified, rank 9), 'paper12' (the paper's form, rank 9 of 12), 'bias3' (biases
    only, ``KE`` held; Liu 2021 §3.3). method: any of :data:`optimizers.METHODS` (default IDE + polish).
    ``bounds``: (lower, upper) for the form's parameters or all 12 (default Liu 2021 Table 1 / 3, count data
    only; for tri9 the installation-error range is doubled, since the gauge folds the triad's rotation into
    Eyx, Ezx, Ezy). ``rng`` (or ``seed``) drives the optimiser. ``weighted``: after the optimiser, re-polish with the
    residuals divided by their sigma (the BLUE-like variant; eq. 7 itself is unweighted).
    ``cov_means`` (3, M, M): full covariance of the static means per axis [output unit^2], e.g. with the
    correlated bias instability of ``calib.signal.noisecov`` (default ``static.cov_axes``; None: independent means
    with std ``static.sigma``). The estimate is unchanged (eq. 7 is unweighted); its covariance is the sandwich
    ``C = J^+ C_r J^+T`` with ``C_r`` from :func:`calib.calibration.covariance.norm_residual_cov`, and
    chi2 = r^T C_r^-1 r.
    """
    needed = {"tri9": 10, "paper12": 10, "bias3": 4}[form]
    require_positions(static, needed, f"the norm calibration (eq. 7, form {form}: "
                      f"{needed - 1} identifiable parameters + 1)")
    rng = np.random.default_rng(seed) if rng is None else rng
    lo, hi = default_bounds(static.sensor, static.output_unit, form, bounds)
    name = "L_a (eq. 7)" if static.sensor == "accel" else "L_g (eq. 7)"
    obj = ob.NormObjective(static.means, static.reference, form=form, sigma=static.sigma, KE=KE, name=name)
    res = opt.minimize(method, obj, (lo, hi), rng, budget, **opts)
    x = res.x
    notes = []
    if weighted:
        obj.weighted = True
        obj.set_weights(x)
        r2 = opt.lsq(obj, (lo, hi), x0=x)
        x = r2.x
        obj.set_weights(x)
    J = obj.jacobian(x)
    scale = hi - lo
    if cov_means is None:
        cov_means = static.cov_axes
    if weighted and cov_means is not None:
        raise ValueError("weighted=True with a full covariance of the means is not implemented; use the "
                         "unweighted fit (the sandwich covariance accounts for the correlation)")
    if weighted:
        cov = cv.weighted_cov(J, scale)
        rw = obj.residuals(x)
        chi2 = float(rw @ rw)
        obj.weighted = False
    elif cov_means is not None:
        C_r = cv.norm_residual_cov(obj, x, cov_means)
        cov = cv.sandwich_full(J, C_r, scale)
        r = obj.residuals(x)
        chi2 = float(r @ np.linalg.solve(C_r, r))
        notes.append("covariance: sandwich with the full covariance of the static means (noise model with the "
                     "slow part, correlated between segments)")
    else:
        sr = obj.residual_sigma(x)
        cov = cv.sandwich(J, sr, scale)
        chi2 = float(np.sum((obj.residuals(x) / sr) ** 2))
    rep = idf.analyze_objective(obj, x, scale, label=f"{static.sensor} {name}, form {form}")
    if form == "tri9":
        frame = FRAME_TRIAD
    elif form == "paper12":
        frame = FRAME_UNDETERMINED
        notes.append("paper's 12-parameter form: rank 9 of 12 - the installation errors are determined only "
                     "through (K E)(K E)^T (see derived['gram']); individual E_ij have no standard error")
    else:
        frame = FRAME_BODY + " (K E held)"
    M, b = obj.form.KE_b(x)
    on_bound = _report_bounds(obj.names, x, lo, hi, notes)
    result = CalibrationResult(sensor=static.sensor, method=f"norm ({method})", form=form, names=obj.names, x=x,
                               cov=cov, KE=M, b=b, input_unit=static.input_unit, output_unit=static.output_unit,
                               frame=frame, objective=name, L=obj.eq7(x), chi2=chi2, dof=static.n - rep.rank,
                               rank=rep.rank, identifiability=rep, on_bound=on_bound, notes=notes, optimizer=res,
                               undetermined=list(rep.undetermined) if rep.rank < len(obj.names) else [])
    if form != "bias3":
        result.derived["gram"] = _gram(obj.form, x, cov)
    return result


def _gram(form, x, cov):
    """(K E)(K E)^T (the combination the norm identifies) and its covariance over the 6 unique entries."""
    M, _ = form.KE_b(x)
    G = M @ M.T
    dM, _ = form.derivatives(x)
    iu = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]
    Jg = np.zeros((6, len(x)))
    for r, (i, j) in enumerate(iu):
        for k in range(3):
            # d(M_ik M_jk) = dM_ik M_jk + M_ik dM_jk
            Jg[r] += dM[3 * i + k] * M[j, k] + M[i, k] * dM[3 * j + k]
    return {"value": G, "entries": iu, "cov": Jg @ cov @ Jg.T}


# ---------------------------------------------------------------------------------------------------------
# gyro: eq. 25 component form, and the paper's L_gm path
# ---------------------------------------------------------------------------------------------------------
def _bias_observations(M, pairs, static, bias_from):
    """Bias observations y_k - M u_k with sigma (weighted mean per axis), see gyro_components."""
    obs, sig = [], []
    if bias_from in ("pairs", "both"):
        y, s = pairs.pair_mean()
        obs.append(y - pairs.mean_input() @ M.T)
        sig.append(s)
    if bias_from in ("static", "both"):
        obs.append(static.means - static.true_inputs() @ M.T)
        sig.append(static.sigma)
    obs, sig = np.concatenate(obs), np.concatenate(sig)
    w = 1.0 / sig**2
    return np.sum(w * obs, axis=0) / np.sum(w, axis=0), obs, sig


def _eq25_covariance(pairs, static, w, bias_from, cov_obs=None):
    """Exact covariance of [vec(K E), b] of :func:`gyro_components` (linear in the means).

    Output axis i only involves column i of the means: row i of K E = P_i (plus_i - minus_i) with the
    weighted least-squares operator P_i of eq. 25, and b_i = sum_k c_ik (o_ik - u_k . M_i) with the
    normalised weights c_ik of the bias observations o_k (pair means and/or static means, inputs u_k).
    With ``cov_obs`` (3, n, n), the covariance of the means of axis i ordered [plus (J), minus (J), static (M)]
    (correlated noise, ``calib.signal.noisecov``): C_i = A C_obs,i A^T instead of A diag(sigma^2) A^T.
    """
    J = pairs.n
    sd = np.hypot(pairs.sigma_plus, pairs.sigma_minus)
    use_p = bias_from in ("pairs", "both")
    use_s = bias_from in ("static", "both")
    nst = static.n if (use_s and static is not None) else 0
    U = []
    if use_p:
        U.append(pairs.mean_input())
    if use_s:
        U.append(static.true_inputs())
    U = np.concatenate(U)
    cov = np.zeros((12, 12))
    for i in range(3):
        Wi = w / sd[:, i:i + 1]
        P = np.linalg.solve(Wi.T @ Wi, Wi.T) / sd[None, :, i]  # (3, J): M_i = P d_i
        sig_o = []
        if use_p:
            sig_o.append(0.5 * sd[:, i])
        if use_s:
            sig_o.append(static.sigma[:, i])
        sig_o = np.concatenate(sig_o)
        c = (1.0 / sig_o**2) / np.sum(1.0 / sig_o**2)
        ubar = c @ U
        n = 2 * J + nst
        A = np.zeros((4, n))
        A[:3, :J] = P
        A[:3, J:2 * J] = -P
        if use_p:
            A[3, :J] += 0.5 * c[:J]
            A[3, J:2 * J] += 0.5 * c[:J]
        if use_s:
            A[3, 2 * J:] += c[-nst:]
        A[3] -= ubar @ A[:3]
        sig = np.concatenate([pairs.sigma_plus[:, i], pairs.sigma_minus[:, i]]
                             + ([static.sigma[:, i]] if nst else []))
        if cov_obs is not None:
            Cobs = np.asarray(cov_obs[i], dtype=float)[:n, :n]
            Ci = A @ Cobs @ A.T
        else:
            Ci = (A * sig[None, :] ** 2) @ A.T
        idx = [3 * i, 3 * i + 1, 3 * i + 2, 9 + i]
        cov[np.ix_(idx, idx)] = Ci
    return cov


def gyro_components(pairs: RotationPairs, static: StaticMeans | None = None, *, bias_from: str = "auto",
                    rng=None, seed: int = 0, budget=(60, 200), bounds=None, cov_obs=None) -> CalibrationResult:
    """Gyro calibration by the component form of Liu 2021 eq. 25 (default gyro method).

    K E from the pair differences: (N+_j - N-_j) = K E (r+_j - r-_j) a_j (linear least squares per output
    row; for a pair about body axis k this is eq. 25: (N+ - N-)/(2 omega) = column k of K E). Biases
    (``bias_from``): 'pairs' = (N+ + N-)/2 - K E (mean input of the pair: Earth rate along the axis);
    'static' = N_m - K E C_n^b omega_ie^n at the static positions; 'both'; 'norm' = static norm (eq. 7) with
    K E held, Liu 2021 §3.3 (needs no attitudes); 'auto' = 'both' if attitudes are known, else 'norm'.
    Covariance: the estimator is linear in the means, propagated exactly (norm: linearised). ``cov_obs``
    (3, n, n): full covariance per axis of the means ordered ``[plus (J), minus (J), static (M)]`` [output unit^2]
    (``calib.signal.noisecov.eq25_cov``; correlated bias instability); not for ``bias_from='norm'``.
    """
    d, sd = pairs.difference()
    w = pairs.delta_input()
    try:
        M, _ = lin.eq25_solve(d, w, sd)
    except ValueError as exc:
        raise SegmentError(str(exc)) from exc
    have_pair_att = pairs.attitude is not None
    have_static_att = static is not None and static.attitude is not None
    if bias_from == "auto":
        bias_from = ("both" if have_pair_att and have_static_att else "pairs" if have_pair_att
                     else "static" if have_static_att else "norm")
    if bias_from in ("static", "both", "norm") and static is None:
        raise SegmentError(f"bias_from={bias_from!r} needs the static gyro means")
    if cov_obs is not None and bias_from == "norm":
        raise ValueError("cov_obs (correlated means) is not implemented for bias_from='norm'")
    notes = [f"K E from the component form of eq. 25 ({pairs.n} pairs); biases from {bias_from}"]
    J, nst = pairs.n, 0 if static is None else static.n
    if bias_from == "norm":
        lo, hi = default_bounds("gyro", static.output_unit, "bias3", None if bounds is None else bounds)
        rng = np.random.default_rng(seed) if rng is None else rng
        o = ob.NormObjective(static.means, static.reference, form="bias3", KE=M)
        b = opt.ide_lsq(o, (lo, hi), rng, budget).x
        y0 = np.concatenate([pairs.plus.ravel(), pairs.minus.ravel(), static.means.ravel()])
        s0 = np.concatenate([pairs.sigma_plus.ravel(), pairs.sigma_minus.ravel(), static.sigma.ravel()])

        def est(y):  # linearised: the polish from b, no new global search
            p = y[:3 * J].reshape(J, 3)
            m = y[3 * J:6 * J].reshape(J, 3)
            st = y[6 * J:].reshape(nst, 3)
            Mx, _ = lin.eq25_solve(p - m, w, sd)
            ox = ob.NormObjective(st, static.reference, form="bias3", KE=Mx)
            return np.concatenate([Mx.ravel(), opt.lsq(ox, (lo, hi), x0=b).x])

        cov_lin = cv.propagate_linear(est, y0, s0)
    else:
        b, _, _ = _bias_observations(M, pairs, static, bias_from)
        cov_lin = _eq25_covariance(pairs, static, w, bias_from, cov_obs)
    # chi-square: pair-difference fit + bias observations' scatter
    rd = (d - w @ M.T) / sd
    chi2 = float(np.sum(rd**2))
    dof = 3 * (J - 3)
    if bias_from != "norm":
        _, obs, sig = _bias_observations(M, pairs, static, bias_from)
        chi2 += float(np.sum(((obs - b) / sig) ** 2))
        dof += 3 * (obs.shape[0] - 1)
    res = _linear_result("gyro", "eq. 25 components", M, b, cov_lin, chi2, dof, static, notes=notes,
                         objective_L=static is not None, units=(pairs.input_unit, pairs.output_unit))
    res.objective = "L_g (eq. 7) at the solution" if static is not None else ""
    if cov_obs is not None:
        res.notes.append("covariance with the full covariance of the means (noise model with the slow part, "
                         "correlated between windows); chi2 uses the independent sigmas")
    res.derived["L_gm"] = ob.LgmObjective(d, w)(ob.Form("ke9").from_KE_b(M))
    return res


def gyro_dynamic(pairs: RotationPairs, static: StaticMeans, *, method: str = "ide_lsq", rng=None, seed: int = 0,
                 budget=(60, 1200), bounds=None, relative: bool = True, **opts) -> CalibrationResult:
    """Liu et al. (2021) §3.3: K and E by minimising L_gm (eq. 26) on the rotation pairs, then the biases by
    minimising L_g (eq. 7) on the static means with K and E held.

    L_gm only constrains the column norms of K E (rank 3 of 9): the installation errors come out
    wherever the optimiser stops inside the bounds, and the biases inherit that error. Reported in
    ``identifiability`` and ``notes``; standard errors of the undetermined parameters are NaN.
    """
    rng = np.random.default_rng(seed) if rng is None else rng
    require_positions(static, 4, "the bias step (eq. 7 with K E held)")
    lo12, hi12 = default_bounds("gyro", static.output_unit, "paper12", bounds)
    d, sd = pairs.difference()
    w = pairs.delta_input()
    lgm = ob.LgmObjective(d, w, sigma_d=sd, form="ke9", relative=relative)
    r1 = opt.minimize(method, lgm, (lo12[:9], hi12[:9]), rng, budget, **opts)
    x1 = r1.x
    J1 = lgm.jacobian(x1)
    scale1 = hi12[:9] - lo12[:9]
    cov1 = cv.sandwich(J1, lgm.residual_sigma(x1), scale1)
    rep1 = idf.analyze_objective(lgm, x1, scale1, label="gyro L_gm (eq. 26)")
    M, _ = ob.Form("ke9").KE_b(x1)
    bias = ob.NormObjective(static.means, static.reference, form="bias3", KE=M, sigma=static.sigma, name="L_g")
    r2 = opt.minimize(method, bias, (lo12[9:], hi12[9:]), rng, budget, **opts)
    b = r2.x
    J2 = bias.jacobian(b)
    cov2 = cv.sandwich(J2, bias.residual_sigma(b), hi12[9:] - lo12[9:])
    x = np.concatenate([x1, b])
    cov = np.zeros((12, 12))
    cov[:9, :9] = cov1
    cov[9:, 9:] = cov2
    notes = [f"L_gm (eq. 26) determines only rank {rep1.rank} of 9 K/E parameters (the column norms of K E); "
             "the installation errors are not determined by it",
             "bias covariance is conditional on the K E found in the first step"]
    on_bound = _report_bounds(PARAM_NAMES, x, lo12, hi12, notes)
    und = list(rep1.undetermined)
    chi2 = float(np.sum((lgm.residuals(x1) / lgm.residual_sigma(x1)) ** 2))
    res = CalibrationResult(sensor="gyro", method=f"dynamic L_gm + L_g ({method})", form="paper12",
                            names=PARAM_NAMES, x=x, cov=cov, KE=M, b=b, input_unit=static.input_unit,
                            output_unit=static.output_unit, frame=FRAME_UNDETERMINED,
                            objective="L_gm (eq. 26)" + (" relative" if relative else ""), L=r1.fun, chi2=chi2,
                            dof=pairs.n - rep1.rank, rank=rep1.rank + 3, identifiability=rep1, on_bound=on_bound,
                            notes=notes, optimizer=r1, undetermined=und)
    res.derived["L_g"] = bias.eq7(b)
    res.derived["lgm_rank"] = (rep1.rank, 9)
    res.derived["bias_optimizer"] = r2
    return res
