"""Where the misfit lives (module doc of :mod:`calib.diagnosis`, step 2): per (sensor, axis); per static phase
the table-angle harmonics and the disagreement between phase means; per rotation pair the sums and
differences of the +/- residuals against |rate|; the phase-quadrature part of the gyro harmonics; the time
course."""
from __future__ import annotations

import math

import numpy as np

from calib.core.distributions import chi2_sf
from calib.diagnosis.geometry import AXES, ROWS, SENSORS
from calib.diagnosis.problem import Fit, Problem, base_estimates

def block_table(prob: Problem, f: Fit):
    """chi-square of fit ``f`` per (sensor, axis) block, with its share of the total."""
    out = []
    for (si, a), idx in prob.geom.obs["blocks"].items():
        c2 = float(np.sum(f.resid_w[idx] ** 2))
        out.append({"sensor": SENSORS[si], "axis": AXES[a] if prob.kind == "vector" else "norm", "chi2": c2,
                    "n_obs": int(idx.size),
                    "share": c2 / f.chi2 if f.chi2 > 0 else 0.0})
    return out


def _window_table(prob: Problem, f: Fit):
    """Standardised residuals (raw residual / sigma) per window, sensor, axis and row."""
    g, o = prob.geom, prob.geom.obs
    z = f.resid / prob.sigma()
    rows = []
    for wi, w in enumerate(g.windows):
        ent = {"window": wi, "label": w.label, "kind": w.kind, "t_start_s": float(g.time_s[w.i0]),
               "duration_s": w.n * g.dt}
        if w.kind == "rotation":
            ent["rate_deg_s"] = w.rate_deg_s
        for si, s in enumerate(SENSORS):
            for r in range(3):
                m = (o["window"] == wi) & (o["sensor"] == si) & (o["row"] == r)
                if m.any():
                    ent[f"{s}_{ROWS[r]}"] = {"residual": f.resid[m].tolist(), "z": z[m].tolist()}
        rows.append(ent)
    return rows


_PAIR_HINT = {
    ("gyro", "sum"): "gyro pair sums see the biases, g-sensitivity, the Earth rate along the axis (latitude) and "
                     "scale asymmetry",
    ("gyro", "difference"): "gyro pair differences see the scale factors and terms odd in the rate (scale "
                            "nonlinearity, a clock offset through the spin-up/down)",
    ("accel", "sum"): "accelerometer pair sums see terms even in the rate (lever arm omega^2 r) and any misfit at "
                      "the axis-up attitude (nonlinearity, asymmetry)",
    ("accel", "difference"): "accelerometer pair differences should vanish: a term odd in the rate (timing, "
                             "table error) is missing",
}


def locate(prob: Problem, f: Fit) -> dict:
    """Where the misfit of fit ``f`` lives (see module doc, step 2). All z-scores are residual / sigma of the
    observation (sigma from the noise model); amplitudes are in the output unit."""
    g, o = prob.geom, prob.geom.obs
    sig = prob.sigma()
    r = f.resid
    out = {"by_sensor_axis": block_table(prob, f)}
    findings = []
    # --- static phases: table-angle harmonics and phase disagreement
    phases = {}
    for wi, w in enumerate(g.windows):
        if w.kind == "static" and w.phase and w.position >= 0:
            phases.setdefault(w.phase, []).append(wi)
    ph_out = []
    for ph, wins in sorted(phases.items()):
        npos = max(g.windows[wi].position for wi in wins) + 1
        step = 360.0 / npos if npos > 0 else 0.0
        th = np.radians([g.windows[wi].position * step for wi in wins])
        hmax = max(1, (len(wins) - 1) // 2)
        cols = [np.ones_like(th)]
        names = ["mean"]
        for h in range(1, hmax + 1):
            cols += [np.cos(h * th), np.sin(h * th)]
            names += [f"cos{h}", f"sin{h}"]
        Xh = np.column_stack(cols)
        if np.linalg.matrix_rank(Xh) < Xh.shape[1]:
            Xh = Xh[:, :np.linalg.matrix_rank(Xh)]
        for si, a in sorted(o["blocks"]):
            s = SENSORS[si]
            idx = np.array([np.flatnonzero((o["window"] == wi) & (o["sensor"] == si) & (o["axis"] == a)
                                           & (o["row"] == 0))[0] for wi in wins])
            zz = r[idx] / sig[idx]
            coef, *_ = np.linalg.lstsq(Xh, zz, rcond=None)
            covh = np.linalg.inv(Xh.T @ Xh)
            harms = []
            for h in range(1, hmax + 1):
                j = 2 * h - 1
                if j + 1 >= Xh.shape[1]:
                    break
                c2 = coef[j:j + 2]
                chi = float(c2 @ np.linalg.solve(covh[j:j + 2, j:j + 2], c2))
                amp = float(np.hypot(*c2) * np.mean(sig[idx]))
                harms.append({"harmonic": h, "amplitude": amp, "chi2_2dof": chi,
                              "p": float(chi2_sf(chi, 2))})
            mean_z = float(coef[0] / math.sqrt(covh[0, 0]))
            ent = {"phase": ph, "sensor": s, "axis": AXES[a], "step_deg": step, "positions": len(wins),
                   "mean_residual": float(np.mean(r[idx])), "mean_z": mean_z, "harmonics": harms}
            ph_out.append(ent)
            for hh in harms:
                if hh["p"] < 1e-3:
                    findings.append((hh["chi2_2dof"], f"{s} {AXES[a]} in phase {ph}: harmonic {hh['harmonic']} of "
                                     f"the table angle, amplitude {hh['amplitude']:.3g} {g.units_out[s]} "
                                     f"(p = {hh['p']:.2g})"))
            if abs(mean_z) > 3.5:
                findings.append((mean_z**2, f"{s} {AXES[a]}: phase {ph} mean residual "
                                 f"{np.mean(r[idx]):.3g} {g.units_out[s]} ({mean_z:+.1f} sigma): phases disagree"))
    out["static_phases"] = ph_out
    # --- rotation pairs: sums and differences against |rate|
    rot = [wi for wi, w in enumerate(g.windows) if w.kind == "rotation"]
    pairs = []
    used = set()
    for i in rot:
        if i in used:
            continue
        wi = g.windows[i]
        for j in rot:
            if j == i or j in used:
                continue
            wj = g.windows[j]
            if np.allclose(wi.axis * wi.rate_deg_s, -wj.axis * wj.rate_deg_s, rtol=1e-6, atol=1e-9):
                pairs.append((i, j) if wi.rate_deg_s > 0 else (j, i))
                used |= {i, j}
                break
    pr_out = []
    for si, a in sorted(o["blocks"]):
        s = SENSORS[si]
        sums, difs, rates, ax_lab = [], [], [], []
        for (p, m) in pairs:
            ip = np.flatnonzero((o["window"] == p) & (o["sensor"] == si) & (o["axis"] == a) & (o["row"] == 0))
            im = np.flatnonzero((o["window"] == m) & (o["sensor"] == si) & (o["axis"] == a) & (o["row"] == 0))
            if not ip.size or not im.size:
                continue
            ip, im = ip[0], im[0]
            sd = 0.5 * math.hypot(sig[ip], sig[im])
            sums.append(((r[ip] + r[im]) / 2, sd))
            difs.append(((r[ip] - r[im]) / 2, sd))
            rates.append(abs(g.windows[p].rate_deg_s))
            ax_lab.append(AXES[int(np.argmax(np.abs(g.windows[p].axis)))])
        if not sums:
            continue
        ent = {"sensor": s, "axis": AXES[a], "pairs": [
            {"rotation_axis": al, "rate_deg_s": rt, "sum": sm[0], "sum_z": sm[0] / sm[1], "difference": df[0],
             "difference_z": df[0] / df[1]} for al, rt, sm, df in zip(ax_lab, rates, sums, difs)]}
        for kind, vals in (("sum", sums), ("difference", difs)):
            zv = np.array([v[0] / v[1] for v in vals])
            chi = float(np.sum(zv**2))
            ent[f"{kind}_chi2"] = chi
            ent[f"{kind}_p"] = float(chi2_sf(chi, zv.size))
            rt = np.array(rates)
            if np.ptp(rt) > 0:
                w = 1.0 / np.array([v[1] for v in vals]) ** 2
                Xr = np.column_stack([np.ones_like(rt), rt])
                cf = np.linalg.solve(Xr.T @ (Xr * w[:, None]), Xr.T @ (w * np.array([v[0] for v in vals])))
                ent[f"{kind}_slope_per_deg_s"] = float(cf[1])
            if ent[f"{kind}_p"] < 1e-3:
                findings.append((chi, f"{s} {AXES[a]}: rotation-pair {kind}s do not fit (chi2 {chi:.1f} on "
                                 f"{zv.size}, p = {ent[kind + '_p']:.2g}); " + _PAIR_HINT[(s, kind)]))
        pr_out.append(ent)
    out["rotation_pairs"] = pr_out
    # --- gyro harmonics: in-phase and quadrature residual against rate (clock offset, Earth-rate magnitude)
    hq = []
    M = base_estimates(f.theta)[0] if prob.kind == "vector" else None
    for wi in (rot if M is not None else []):
        w = g.windows[wi]
        if w.rows < 3:
            continue
        for a in range(3):
            ic = np.flatnonzero((o["window"] == wi) & (o["sensor"] == 1) & (o["axis"] == a) & (o["row"] == 1))
            isn = np.flatnonzero((o["window"] == wi) & (o["sensor"] == 1) & (o["axis"] == a) & (o["row"] == 2))
            if not ic.size:
                continue
            pred = prob.X0[[ic[0], isn[0]]][:, 12 + 3 * a:15 + 3 * a] @ M["gyro"][a]
            amp = float(np.hypot(*pred))
            if amp <= 0:
                continue
            u = pred / amp
            res2 = np.array([r[ic[0]], r[isn[0]]])
            inph = float(res2 @ u)
            quad = float(u[0] * res2[1] - u[1] * res2[0])
            sd = float(sig[ic[0]])
            hq.append({"window": w.label, "axis": AXES[a], "rate_deg_s": w.rate_deg_s, "amplitude": amp,
                       "in_phase": inph, "quadrature": quad, "in_phase_z": inph / sd, "quadrature_z": quad / sd})
    if hq:
        zq = np.array([h["quadrature_z"] for h in hq])
        rq = np.array([h["rate_deg_s"] for h in hq])
        chi = float(np.sum(zq**2))
        out["gyro_harmonics"] = {"windows": hq, "quadrature_chi2": chi, "n": int(zq.size),
                                 "quadrature_p": float(chi2_sf(chi, zq.size)),
                                 "quadrature_vs_rate_corr": float(np.corrcoef(zq, rq)[0, 1]) if zq.size > 2 else 0.0}
        if out["gyro_harmonics"]["quadrature_p"] < 1e-3:
            findings.append((chi, f"gyro: the table-angle harmonics are phase-shifted (quadrature chi2 {chi:.1f} on "
                             f"{zq.size}); a shift that grows with the signed rate points to a clock offset"))
    # --- time course
    nb = 6
    tw = np.array([g.time_s[w.i0] for w in g.windows])
    edges = np.linspace(tw.min(), tw.max() + 1e-9, nb + 1)
    tbins = []
    z = r / sig
    for b in range(nb):
        wins = np.flatnonzero((tw >= edges[b]) & (tw < edges[b + 1]))
        m = np.isin(o["window"], wins)
        if m.any():
            tbins.append({"t0_s": float(edges[b]), "t1_s": float(edges[b + 1]), "n_obs": int(m.sum()),
                          "mean_z2": float(np.mean(z[m] ** 2))})
    trends = []
    for si, a in sorted(o["blocks"]):
        s = SENSORS[si]
        m = (o["sensor"] == si) & (o["axis"] == a) & (o["row"] == 0)
        if m.sum() < 3:
            continue
        t = tw[o["window"][m]]
        wgt = 1.0 / sig[m] ** 2
        Xt = np.column_stack([np.ones_like(t), t / 3600.0])
        A_ = Xt.T @ (Xt * wgt[:, None])
        cf = np.linalg.solve(A_, Xt.T @ (wgt * r[m]))
        se = math.sqrt(np.linalg.inv(A_)[1, 1])
        trends.append({"sensor": s, "axis": AXES[a], "slope_per_h": float(cf[1]), "slope_z": float(cf[1] / se)})
        if abs(cf[1] / se) > 4:
            findings.append(((cf[1] / se) ** 2, f"{s} {AXES[a]}: residuals trend with time "
                             f"({cf[1]:.3g} {g.units_out[s]} per h, {cf[1] / se:+.1f} sigma; note: segment means "
                             "are correlated in time, this z is indicative)"))
    out["time"] = {"bins": tbins, "trends": trends}
    out["per_segment"] = _window_table(prob, f)
    findings.sort(key=lambda x: -x[0])
    out["summary"] = [txt for _, txt in findings[:8]]
    return out
