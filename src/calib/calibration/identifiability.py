"""Which calibration parameters a set of observations determines: SVD of the column-scaled Jacobian.

At a solution theta, the residual Jacobian J (n_obs x p) tells which parameter directions change the
residuals to first order. Columns are scaled by a typical size of each parameter (default: the width of
its search bounds, Liu 2021 Tables 1 and 3), J_s = J diag(s), and

    J_s = U S V^T;   numerical rank = #{S_k > rtol * S_1};   null space = columns of V beyond the rank.

A null-space direction v (scaled coordinates) corresponds to the parameter change delta theta = s * v that
leaves every residual unchanged: those combinations are not determined by the data, whatever the noise.
Without typical sizes each column is divided by its norm (:func:`column_scaled`); :func:`rank_summary` gives rank,
condition and the weakest direction of such a Jacobian (the field calibration's check). Both reports rest on the
one SVD, :func:`singular_spectrum`.

Known null spaces, named here in parameter terms:

* Norm objectives (Liu 2021 eq. 7), paper form of 12 parameters: ``|(K E)^-1 (N - b)|`` is invariant under
  K E -> K E R for a rotation R (rotating the whole triad in the body frame); the three infinitesimal
  rotations about body x, y, z are null directions -> rank 9 of 12 on the 24-position path.
  (About z, to first order: delta Exy = -phi, delta Eyx = +phi: only Exy + Eyx is determined.)
* L_gm (Liu 2021 eq. 26) with rotations about the three body axes: only |K E a_j|^2 enters, i.e. the three
  column norms of K E -> rank 3 of the 9 K/E parameters; the six installation errors are undetermined.
  Rotations about axes between the body axes add the angles between columns ((K E)^T (K E) off-diagonal,
  rank 6); K E -> R K E (a rotation of the output triad) is never determined by eq. 26.

:func:`check_plan` runs the same analysis on a planned path before any data exist (noise-free synthetic
observations from a nominal model at the planned attitudes / rates) and suggests what to add.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from calib.core import earth
from calib.calibration import objectives as ob
from calib.core.triad import liu2021_bounds, liu2021_model

AXIS_NAMES = ("x", "y", "z")


@dataclass
class IdentifiabilityReport:
    """Numerical rank and null space of a column-scaled residual Jacobian.

    ``null_vectors`` (k, p) are the null directions in *parameter units* (delta theta), ``descriptions``
    names each of them, ``determined`` / ``undetermined`` list parameters whose own direction has a
    null-space component below / above ``tol_param`` (scaled coordinates).
    """

    rank: int
    n_params: int
    names: tuple
    singular_values: np.ndarray
    scale: np.ndarray
    null_vectors: np.ndarray
    descriptions: list
    determined: list
    undetermined: list
    generators_in_null: dict = field(default_factory=dict)
    suggestions: list = field(default_factory=list)
    label: str = ""

    @property
    def deficiency(self) -> int:
        return self.n_params - self.rank

    def summary(self) -> str:
        lines = [f"{self.label + ': ' if self.label else ''}rank {self.rank} of {self.n_params}"]
        if self.descriptions:
            lines.append("not determined (null-space directions):")
            lines += [f"  - {d}" for d in self.descriptions]
        if self.generators_in_null:
            named = [k for k, v in self.generators_in_null.items() if v > 0.999]
            if named:
                lines.append("symmetries in the null space: " + "; ".join(named))
        lines.append("determined parameters: " + (", ".join(self.determined) or "none"))
        if self.undetermined:
            lines.append("parameters not determined individually: " + ", ".join(self.undetermined))
        for s in self.suggestions:
            lines.append(f"suggestion: {s}")
        return "\n".join(lines)


def _describe(v_scaled, scale, names, tol=0.05):
    """Text of one null direction: delta theta in parameter units, normalised so that the component that is
    largest in scaled coordinates is +1; components below ``tol`` (scaled, relative) are left out."""
    k = int(np.argmax(np.abs(v_scaled)))
    v = v_scaled * scale
    u = v / v[k]
    parts = []
    for j in np.argsort(-np.abs(v_scaled)):
        if abs(v_scaled[j]) < tol * abs(v_scaled[k]):
            continue
        parts.append(f"{u[j]:+.3g}*{names[j]}")
    return "delta " + " ".join(parts)


def column_scaled(J, scale=None):
    """The Jacobian ``J`` (n, p) with its columns scaled: J diag(s) for typical parameter sizes ``scale`` (p,),
    or, without them, each column divided by its norm (all-zero columns kept as they are)."""
    J = np.asarray(J, dtype=float)
    if scale is None:
        norms = np.linalg.norm(J, axis=0)
        return J / np.where(norms > 0, norms, 1.0)
    return J * np.asarray(scale, dtype=float)[None, :]


def singular_spectrum(Js):
    """The one identifiability SVD: singular values (p,) of a column-scaled Jacobian ``Js`` (n, p), padded with
    zeros when n < p (directions the observations cannot see at all), and the right singular vectors Vt (p, p).
    The rank of the data is the number of singular values above a relative tolerance of the largest."""
    Js = np.asarray(Js, dtype=float)
    _, S, Vt = np.linalg.svd(Js, full_matrices=True)
    Sfull = np.zeros(Js.shape[1])
    Sfull[: len(S)] = S
    return Sfull, Vt


@dataclass
class RankSummary:
    """Rank, condition and weakest direction of a Jacobian whose columns are divided by their norms.

    ``singular_values`` are relative to the largest (descending). ``weakest`` maps each parameter name to its
    component in the right singular vector of the smallest singular value (sign: largest component positive).
    """

    n_params: int
    rank: int
    singular_values: np.ndarray
    condition: float
    weakest: dict
    rtol: float
    based_on: str

    def as_dict(self) -> dict:
        top = sorted(self.weakest.items(), key=lambda kv: -abs(kv[1]))
        return {"n_params": self.n_params, "rank": self.rank, "condition": self.condition, "rtol": self.rtol,
                "singular_values_rel": [float(s) for s in self.singular_values],
                "weakest_direction": {k: round(float(v), 4) for k, v in top if abs(v) >= 0.05},
                "based_on": self.based_on}

    def describe(self) -> str:
        w = ", ".join(f"{v:+.2f} {k}" for k, v in sorted(self.weakest.items(), key=lambda kv: -abs(kv[1]))
                      if abs(v) >= 0.2)
        return (f"rank {self.rank} of {self.n_params} (rtol {self.rtol:g}; condition {self.condition:.3g}); "
                f"weakest direction {w} (relative singular value {self.singular_values[-1]:.3g})")


def rank_summary(jac, names, rtol: float = 1e-6, based_on: str = "") -> RankSummary:
    """:class:`RankSummary` of the Jacobian ``jac`` (rows = observations, one column per name in ``names``):
    columns divided by their norms (:func:`column_scaled`), then :func:`singular_spectrum`; rank = number of
    relative singular values above ``rtol``."""
    s_full, vt = singular_spectrum(column_scaled(jac))
    rel = s_full / s_full[0] if s_full[0] > 0 else s_full
    rank = int(np.sum(rel > rtol))
    weakest = vt[-1] * (1.0 if vt[-1][np.argmax(np.abs(vt[-1]))] > 0 else -1.0)
    cond = float(s_full[0] / s_full[-1]) if s_full[-1] > 0 else math.inf
    return RankSummary(len(names), rank, rel, cond, dict(zip(names, weakest.tolist())), rtol, based_on)


def analyze_jacobian(J, names, scale=None, *, rtol: float = 1e-8, tol_param: float = 1e-2, generators=None,
                     label: str = "") -> IdentifiabilityReport:
    """Rank / null space of residual Jacobian ``J`` (n, p) with column scale ``scale`` (p,).

    ``generators``: optional dict name -> delta theta (p,) of known symmetry directions (parameter units);
    the report gives, for each, the fraction of its (scaled) length lying in the null space.
    """
    J = np.asarray(J, dtype=float)
    p = J.shape[1]
    s = np.ones(p) if scale is None else np.asarray(scale, dtype=float)
    Sfull, Vt = singular_spectrum(column_scaled(J, s))
    smax = Sfull.max() if Sfull.size else 0.0
    rank = int(np.sum(Sfull > rtol * smax)) if smax > 0 else 0
    Vn = Vt[rank:].T  # (p, k) scaled coordinates
    # parameter-aligned basis of the null space: greedily project the unit vectors of the parameters
    P = Vn @ Vn.T
    basis = []
    Pw = P.copy()
    for _ in range(p - rank):
        norms = np.linalg.norm(Pw, axis=0)
        j = int(np.argmax(norms))
        if norms[j] < 1e-12:
            break
        v = Pw[:, j] / norms[j]
        basis.append(v)
        Pw = Pw - np.outer(v, v @ Pw)
    null_scaled = np.array(basis) if basis else np.zeros((0, p))
    null_params = null_scaled * s[None, :]
    desc = [_describe(v, s, names) for v in null_scaled]
    comp = np.linalg.norm(P, axis=0)  # null-space component of each parameter's unit direction
    determined = [names[j] for j in range(p) if comp[j] < tol_param]
    undetermined = [names[j] for j in range(p) if comp[j] >= tol_param]
    gen_frac = {}
    if generators:
        for gname, g in generators.items():
            gs = np.asarray(g, dtype=float) / s
            ng = np.linalg.norm(gs)
            gen_frac[gname] = float(np.linalg.norm(P @ gs) / ng) if ng > 0 else 0.0
        # name the null directions that are (almost) a single generator
        for i, v in enumerate(null_scaled):
            for gname, g in generators.items():
                gs = np.asarray(g, dtype=float) / s
                ng = np.linalg.norm(gs)
                if ng > 0 and abs(v @ gs) / ng > 0.99:
                    desc[i] = f"{gname}: {desc[i]}"
                    break
    return IdentifiabilityReport(rank=rank, n_params=p, names=tuple(names), singular_values=Sfull, scale=s,
                                 null_vectors=null_params, descriptions=desc, determined=determined,
                                 undetermined=undetermined, generators_in_null=gen_frac, label=label)


# ---------------------------------------------------------------------------------------------------------
# named symmetry directions
# ---------------------------------------------------------------------------------------------------------
def _dtheta_from_dM(form: ob.Form, theta, dM, db=None):
    """Parameter change of ``form`` for a change dM of K E (and db of b), first order (least squares)."""
    dMdt, dbdt = form.derivatives(theta)
    A = np.vstack([dMdt, dbdt])
    rhs = np.concatenate([np.asarray(dM, float).ravel(), np.zeros(3) if db is None else np.asarray(db, float)])
    return np.linalg.lstsq(A, rhs, rcond=None)[0]


def rotation_generators(form: ob.Form, theta, side: str = "right"):
    """Infinitesimal rotations of the triad as parameter directions.

    side='right': K E -> K E (I + [e_k x]) (the input frame rotates: invisible to the norm, eq. 7);
    side='left': K E -> (I + [e_k x]) K E (the output vector rotates: invisible to |K E w|, eq. 26).
    """
    M, _ = form.KE_b(theta)
    out = {}
    for k in range(3):
        e = np.zeros(3)
        e[k] = 1.0
        S = np.array([[0.0, -e[2], e[1]], [e[2], 0.0, -e[0]], [-e[1], e[0], 0.0]])
        dM = M @ S if side == "right" else S @ M
        what = ("rotation of the triad about body " if side == "right" else "rotation of the output triad about ")
        out[what + AXIS_NAMES[k]] = _dtheta_from_dM(form, theta, dM)
    return out


def analyze_objective(objective, theta, scale=None, *, rtol=1e-8, label="") -> IdentifiabilityReport:
    """:func:`analyze_jacobian` of ``objective.jacobian(theta)`` with the symmetry generators of its kind."""
    J = objective.jacobian(theta)
    gens = None
    kind = getattr(objective, "kind", "")
    form = objective.form
    if form.name in ("paper12", "ke9"):  # forms that can represent a rotation of K E
        if kind == "norm":
            gens = rotation_generators(form, theta, "right")
        elif kind == "lgm":
            gens = rotation_generators(form, theta, "left")
    return analyze_jacobian(J, objective.names, scale, rtol=rtol, generators=gens, label=label)


def default_scale(sensor: str, form_name: str):
    """Bound widths of Liu 2021 Table 1 (accel) / 3 (gyro) for the parameters of ``form_name``."""
    lo, hi = liu2021_bounds(sensor)
    return (hi - lo)[form_indices(form_name)]


def form_indices(form_name: str):
    """Indices of a form's parameters in the paper's 12-vector."""
    return {"paper12": list(range(12)), "tri9": [0, 1, 2, 5, 7, 8, 9, 10, 11], "ke9": list(range(9)),
            "bias3": [9, 10, 11]}[form_name]


# ---------------------------------------------------------------------------------------------------------
# planned paths
# ---------------------------------------------------------------------------------------------------------
def liu2021_attitudes():
    """The 24 nominal attitudes C_b^n (body right-front-up -> ENU) of Liu 2021 §2.2, Figure 1.

    Phase k (k = x, y, z) points body axis k north and turns it in 45 deg steps about that axis. Start
    attitudes: phase 1 x north, z up (y west); phase 2 y north, z up (x east); phase 3 z north, x up (y east).
    """
    c0 = [np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), np.eye(3),
          np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])]
    out = []
    for ph in range(3):
        for k in range(8):
            a = math.radians(45.0 * k)
            c, s_ = math.cos(a), math.sin(a)
            if ph == 0:
                R = np.array([[1, 0, 0], [0, c, -s_], [0, s_, c]])
            elif ph == 1:
                R = np.array([[c, 0, s_], [0, 1, 0], [-s_, 0, c]])
            else:
                R = np.array([[c, -s_, 0], [s_, c, 0], [0, 0, 1]])
            out.append(c0[ph] @ R)
    return np.array(out)


def liu2021_rotation_plan(rates_deg_s=(10.0, 20.0, 30.0)):
    """Liu et al. (2021) §3.3 / Figure 7: + and - rotations about body x, y, z at 10, 20, 30 deg/s -> (axes (J,3),
    rates (J,)) of the J = 9 pairs (rate = |rate| of the + rotation)."""
    axes, rates = [], []
    for k in range(3):
        for r in rates_deg_s:
            a = np.zeros(3)
            a[k] = 1.0
            axes.append(a)
            rates.append(r)
    return np.array(axes), np.array(rates, dtype=float)


def cube_attitudes():
    """The 24 attitudes with body axes along +-E, +-N, +-U (candidates for additional static positions)."""
    out = []
    eye = np.eye(3)
    for i in range(3):
        for si in (1, -1):
            for j in range(3):
                if j == i:
                    continue
                for sj in (1, -1):
                    x = si * eye[i]
                    y = sj * eye[j]
                    out.append(np.column_stack([x, y, np.cross(x, y)]))
    return np.array(out)


def _static_objective(sensor, model, attitudes, form, latitude_deg, in_unit):
    if sensor == "accel":
        g = float(earth.normal_gravity(math.radians(latitude_deg)))
        ref = g / 9.80665 if in_unit == "g" else g
        v_n = np.array([0.0, 0.0, ref])
    else:
        w = earth.earth_rate_enu(math.radians(latitude_deg))
        f = earth.DEG_PER_H if in_unit == "deg h-1" else 1.0
        v_n = w / f
        ref = float(np.linalg.norm(v_n))
    x = np.einsum("mji,j->mi", attitudes, v_n)
    N = model.forward(x)
    return ob.NormObjective(N, ref, form=form), x, N


def _truth_vector(model, form_name):
    M = model.KE
    if form_name == "tri9":
        L, _ = ob.lower_triangular_gauge(M)
        return ob.Form("tri9").from_KE_b(L, model.b)
    return ob.Form(form_name).from_KE_b(M, model.b)


def check_plan(sensor: str = "accel", form: str = "paper12", *, attitudes=None, rotation_axes=None,
               rotation_rates=None, latitude_deg: float = 39.98, model=None, rtol: float = 1e-8,
               candidates=None, max_add: int = 4) -> IdentifiabilityReport:
    """Identifiability of a *planned* calibration path, before data exist.

    ``form``: 'paper12' | 'tri9' (norm eq. 7 on the static attitudes), 'vector' (classical calibration with
    the attitudes known: linear, 12 parameters), 'lgm' (eq. 26 on the rotation pairs, 9 K/E parameters),
    'eq25' (component form of eq. 25, 9 K/E parameters). ``attitudes`` (M, 3, 3) C_b^n of the static
    positions (default: Liu 2021's 24); ``rotation_axes`` (J, 3) body axes and ``rotation_rates`` (J,) deg/s
    of the + rotations (default: Liu 2021's 9 pairs). Noise-free observations come from ``model``
    (default: Liu 2021's 'separate calibration results' of Table 1 / 3).
    Suggestions say what to add (computed: candidate attitudes or axes are tried, not assumed).
    """
    model = model or liu2021_model(sensor)
    in_unit = model.input_unit
    if form in ("paper12", "tri9", "vector"):
        att = liu2021_attitudes() if attitudes is None else np.asarray(attitudes, dtype=float)
        rep = _static_report(sensor, model, att, form, latitude_deg, in_unit, rtol)
        sugg = []
        full = 9 if form in ("paper12", "tri9") else 12
        if form == "paper12":
            sugg.append("the norm (eq. 7) cannot determine the orientation of the triad (3 rotation angles): no "
                        "static position can fix this; use form 'tri9' (K E lower triangular, the 9 combinations "
                        "the norm does determine) or a vector calibration with known attitudes")
        if rep.rank < full:
            cand = (np.concatenate([cube_attitudes(), liu2021_attitudes()]) if candidates is None
                    else np.asarray(candidates, dtype=float))
            cur = att
            added = []
            for _ in range(max_add):
                best = None
                for c in cand:
                    r = _static_report(sensor, model, np.concatenate([cur, c[None]]), form, latitude_deg, in_unit,
                                       rtol)
                    key = (r.rank, r.singular_values[r.rank - 1] if r.rank else 0.0)
                    if best is None or key > best[0]:
                        best = (key, c, r)
                if best is None or best[0][0] <= _static_report(sensor, model, cur, form, latitude_deg, in_unit,
                                                                rtol).rank:
                    break
                cur = np.concatenate([cur, best[1][None]])
                added.append(best[1])
                if best[2].rank >= full:
                    break
            if added:
                r_new = _static_report(sensor, model, cur, form, latitude_deg, in_unit, rtol)
                txt = "; ".join(_attitude_text(c) for c in added)
                sugg.append(f"add {len(added)} static position(s) [{txt}] -> rank {r_new.rank} of {rep.n_params}")
            else:
                sugg.append(f"with {len(att)} positions the rank is {rep.rank}; no single added candidate "
                            "position raises it")
        rep.suggestions = sugg
        return rep
    if form in ("lgm", "eq25"):
        if rotation_axes is None:
            axes, rates = liu2021_rotation_plan()
        else:
            axes = np.asarray(rotation_axes, dtype=float)
            rates = np.asarray(rotation_rates, dtype=float) if rotation_rates is not None else np.full(len(axes), 10.)
        rep = _rotation_report(sensor, model, axes, rates, form, rtol)
        sugg = []
        if form == "lgm":
            diag = np.array([[1, 1, 0], [1, 0, 1], [0, 1, 1]], dtype=float) / math.sqrt(2.0)
            r6 = _rotation_report(sensor, model, np.concatenate([axes, diag]),
                                  np.concatenate([rates, np.full(3, rates.max())]), form, rtol)
            sugg.append(f"L_gm (eq. 26) only sees |K E a|^2 per rotation axis a: adding + and - rotations about "
                        f"(x+y)/sqrt2, (x+z)/sqrt2, (y+z)/sqrt2 gives rank {r6.rank} of 9; the rest (K E -> R K E, "
                        "a rotation of the output triad) is never determined by eq. 26 - use the component form "
                        "of eq. 25 (rank 9 with rotations about three axes)")
        elif rep.rank < 9:
            sugg.append("add + and - rotations about the missing body axes (eq. 25 needs three non-coplanar axes)")
        rep.suggestions = sugg
        return rep
    raise ValueError(f"form must be one of paper12, tri9, vector, lgm, eq25; got {form!r}")


def _attitude_text(C):
    names = ["E", "N", "U"]
    parts = []
    for k in range(3):
        col = C[:, k]
        i = int(np.argmax(np.abs(col)))
        parts.append(f"{AXIS_NAMES[k]}->{'+' if col[i] > 0 else '-'}{names[i]}")
    return " ".join(parts)


def _static_report(sensor, model, att, form, latitude_deg, in_unit, rtol):
    if form == "vector":
        _, x, _ = _static_objective(sensor, model, att, "paper12", latitude_deg, in_unit)
        # N_m,i = [x_m, 1] . [M_i, b_i]: block-diagonal linear design over [vec M row-major, b]
        n = len(att)
        J = np.zeros((3 * n, 12))
        for i in range(3):
            J[i::3, 3 * i:3 * i + 3] = x
            J[i::3, 9 + i] = 1.0
        names = tuple(f"KE{r}{c}" for r in "xyz" for c in "xyz") + ("bx", "by", "bz")
        K = np.abs(np.diag(model.KE)).mean()
        lo, hi = liu2021_bounds(sensor)
        scale = np.concatenate([np.full(9, K * 0.02), hi[9:] - lo[9:]])
        return analyze_jacobian(J, names, scale, rtol=rtol, label=f"{sensor} vector calibration, {n} positions")
    o, _, _ = _static_objective(sensor, model, att, form, latitude_deg, in_unit)
    theta = _truth_vector(model, form)
    return analyze_objective(o, theta, default_scale(sensor, form), rtol=rtol,
                             label=f"{sensor} norm (eq. 7), form {form}, {len(att)} positions")


def _rotation_report(sensor, model, axes, rates, form, rtol):
    f = earth.DEG / (earth.DEG_PER_H if model.input_unit == "deg h-1" else 1.0)
    w = 2.0 * rates[:, None] * axes * f  # 2 omega_0^b in the input unit
    d = w @ model.KE.T
    theta = ob.Form("ke9").from_KE_b(model.KE)
    scale = default_scale(sensor, "ke9")
    if form == "lgm":
        o = ob.LgmObjective(d, w, form="ke9")
        return analyze_objective(o, theta, scale, rtol=rtol, label=f"{sensor} L_gm (eq. 26), {len(axes)} pairs")
    J = np.zeros((3 * len(axes), 9))
    dM, _ = ob.Form("ke9").derivatives(theta)
    for j in range(len(axes)):
        for i in range(3):
            row = np.zeros(9)
            row[3 * i:3 * i + 3] = w[j]
            J[3 * j + i] = -row @ dM
    return analyze_jacobian(J, ob.FORM_NAMES["ke9"], scale, rtol=rtol,
                            label=f"{sensor} eq. 25 component form, {len(axes)} pairs")
