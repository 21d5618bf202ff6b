"""The Ferraris closed form for labelled sessions (each axis up and down, one known turn per axis; imucal's
sessions): ``N = M f + b``, calibration ``M^-1 (N - b)``."""
from __future__ import annotations

import math
import re

import numpy as np

from calib.calibration.identifiability import rank_summary
from calib.fieldcal.results import (
    BIAS_NAMES,
    FERRARIS_M_NAMES,
    FieldCalError,
    TriadFit,
    input_label,
    scale_factor_units,
)

# =========================================================================== Ferraris (labelled sessions)

LABEL_PATTERN = re.compile(r"^([xyz])_([pa])$")


def fit_ferraris(accel, gyro, fs: float, statics: dict, turns: list, gravity: float, *,
                 accel_units="count", accel_factor=1.0, gyro_units="count", gyro_factor=1.0,
                 input_kind="rate", dt=None, path=None):
    """Ferraris calibration from labelled static positions and known turns (imucal's sessions).

    ``statics``: ``{label: sample index array}`` with imucal labels ``x_p`` (x up: accel reads +g on x),
    ``x_a`` (x down), ... -- all six. The norm model (9 parameters) is not determined by six orientations, so
    the labels are used as *vector* observations of ``N = M f + b`` with ``f = +-g`` along the labelled axis
    (12 unknowns, 18 equations), solved in Ferraris' closed form: ``M`` columns ``(N+ - N-) / 2g`` (also the
    least-squares solution), ``b_i`` the midpoint of the on-axis components of the i-axis pair (Ferraris
    eq. 20; the least-squares ``b``, the mean of all six, absorbs the tilt of hand-placed positions and is
    reported for comparison only). Scale factors = row norms of ``M`` (imucal's ``K_a``). ``turns``: ``[(axis 0..2, angle_rad, sample index
    array)]``, angles signed by the right-hand rule: gyro bias = mean over the static samples, ``M_g`` columns
    = integrated bias-free gyro / angle. Inputs in the calibration's input units. Returns (accel, gyro)
    :class:`TriadFit`.
    """
    accel = np.asarray(accel, dtype=float)
    gyro = np.asarray(gyro, dtype=float)
    need = [f"{a}_{s}" for a in "xyz" for s in "pa"]
    missing = [lab for lab in need if lab not in statics]
    if missing:
        raise FieldCalError(f"{path or 'input'}: Ferraris needs the six labelled static positions {need}; "
                            f"missing {missing} -- fix: label them (imucal convention) or use method 'norm'")
    F, Nm, n_per = [], [], []
    for lab in need:
        ax, sgn = "xyz".index(lab[0]), (1.0 if lab[2] == "p" else -1.0)
        f = np.zeros(3)
        f[ax] = sgn * gravity
        F.append(np.concatenate([f, [1.0]]))
        Nm.append(accel[statics[lab]].mean(axis=0))
        n_per.append(len(statics[lab]))
    F, Nm = np.array(F), np.array(Nm)
    up, down = Nm[0::2], Nm[1::2]  # rows: x, y, z positions
    M = (up - down).T / (2.0 * gravity)  # columns: Ferraris eq. 21-22, N+ - N- = 2 g M e_i
    b = np.diag((up + down).T / 2.0).copy()  # Ferraris eq. 20: on-axis midpoints only
    res = Nm - F[:, :3] @ M.T - b  # off-axis placement scatter (on-axis entries are zero by construction)
    dof = Nm.size - 12
    sigma2 = float(np.sum(res * res)) / dof
    cov = np.zeros((12, 12))
    for r in range(3):  # each entry of M from one difference of two means, each b_r from one sum
        cov[3 * r:3 * r + 3, 3 * r:3 * r + 3] = np.eye(3) * sigma2 / (2.0 * gravity ** 2)
        cov[9 + r, 9 + r] = sigma2 / 2.0
    C = np.linalg.inv(M)
    sf = np.linalg.norm(M, axis=1)
    sf_std = np.full(3, math.sqrt(sigma2 / (2.0 * gravity ** 2)))
    ident = rank_summary(F, ("f_x", "f_y", "f_z", "1"), based_on="Ferraris design (six labelled positions)")
    # the full linear least squares (b = mean of the six) for comparison: sensitive to placement tilt
    X_ls, *_ = np.linalg.lstsq(F, Nm, rcond=None)
    b_ls = X_ls[3]
    static_idx = np.concatenate([statics[lab] for lab in need])
    cal = (accel[static_idx] - b) @ C.T
    r = np.linalg.norm(cal, axis=1) - gravity
    r_ls = np.linalg.norm((accel[static_idx] - b_ls) @ C.T, axis=1) - gravity
    in_a = input_label("accel", accel_units, input_kind)
    dt_s = 1.0 / fs if dt is None else dt
    acc = TriadFit(
        sensor="accel", method="ferraris", names=FERRARIS_M_NAMES + BIAS_NAMES,
        values=np.concatenate([M.ravel(), b]), covariance=cov,
        param_units=(f"{in_a} per m s-2",) * 9 + (in_a,) * 3, matrix=C, bias=b, input_units=accel_units,
        input_factor=float(accel_factor), input_kind=input_kind, dt=dt_s, output_units="m s-2",
        scale_factors=sf, scale_factor_std=sf_std,
        scale_factor_units=scale_factor_units("accel", accel_units, in_a),
        residual_rms=float(np.sqrt(np.mean(r * r))), residual_units="m s-2", n_residuals=int(len(r)),
        identifiability=ident,
        notes=["six static positions cannot determine the nine-parameter norm model (6 norm equations, 9 "
               "unknowns); the labelled orientations are used as vector observations instead: N = M f + b with "
               "f = +-g along the labelled axis, Ferraris closed form (M columns (N+ - N-) / 2g, bias from the "
               "on-axis midpoints, which hand-placement tilt barely affects)",
               f"the full least-squares bias (mean of the six positions) would give a static-norm RMS of "
               f"{float(np.sqrt(np.mean(r_ls ** 2))):.4g} m s-2 (placement tilt leaks into it)"],
        extra={"position_residuals": res, "sigma_placement": math.sqrt(sigma2), "labels": need,
               "samples_per_position": n_per, "static_norm_rms_lsq_bias": float(np.sqrt(np.mean(r_ls ** 2)))})
    if len(turns) != 3 or sorted(t[0] for t in turns) != [0, 1, 2]:
        raise FieldCalError(f"{path or 'input'}: Ferraris gyro needs one turn about each axis x, y, z; got axes "
                            f"{[t[0] for t in turns]} -- fix: label x_rot, y_rot, z_rot")
    bg = gyro[static_idx].mean(axis=0)
    W = np.zeros((3, 3))
    angles = np.zeros(3)
    for ax, ang, idx in turns:
        W[:, ax] = (gyro[idx] - bg).sum(axis=0) * dt_s
        angles[ax] = ang
    Mg = W / angles[None, :]
    Cg = np.linalg.inv(Mg)
    turn_out = {}
    for ax, ang, idx in turns:
        integ = ((gyro[idx] - bg) @ Cg.T).sum(axis=0) * dt_s
        turn_out["xyz"[ax]] = np.degrees(integ)
    sfg = np.linalg.norm(Mg, axis=1)
    bg_std = gyro[static_idx].std(axis=0, ddof=1) / math.sqrt(len(static_idx))
    covg = np.full((12, 12), np.nan)
    covg[9:, 9:] = np.diag(bg_std ** 2)
    in_g = input_label("gyro", gyro_units, input_kind)
    gyr = TriadFit(
        sensor="gyro", method="ferraris", names=FERRARIS_M_NAMES + BIAS_NAMES,
        values=np.concatenate([Mg.ravel(), bg]), covariance=covg,
        param_units=(f"{in_g} per rad s-1",) * 9 + (in_g,) * 3, matrix=Cg, bias=bg, input_units=gyro_units,
        input_factor=float(gyro_factor), input_kind=input_kind, dt=dt_s, output_units="rad s-1",
        scale_factors=sfg, scale_factor_std=np.full(3, np.nan),
        scale_factor_units=scale_factor_units("gyro", gyro_units, in_g),
        residual_rms=0.0, residual_units="deg", n_residuals=0, identifiability=None,
        notes=["three turns determine the nine entries of M_g exactly (no redundancy: no residual, no "
               "covariance); bias from the static positions; gyro g-sensitivity not modelled"],
        extra={"turn_angles_deg": turn_out, "declared_angles_deg": np.degrees(angles)})
    return acc, gyr
