"""Population optimisers of Liu 2021 §3 and their competitors, behind one interface.

Every method has the signature::

    method(objective, bounds, rng, budget=(NP, EG), **opts) -> Result

* ``objective`` maps a population (P, D) to values (P,) to be *minimised* (L of Liu 2021 eqs. 7 / 26; the
  paper maximises the fitness f = 1 / L, eqs. 10 and 20, which is the same thing). Least-squares methods also
  need ``objective.residuals(x)`` and (optionally) ``objective.jacobian(x)``.
* ``bounds`` = (lower (D,), upper (D,)) or a sequence of (lo, hi) pairs (Liu 2021 Tables 1 and 3).
* ``rng`` a ``numpy.random.Generator``; every random draw comes from it, so a run is reproducible from its seed.
* ``budget`` = (NP, EG): population size and number of generations; every population method spends
  NP x (EG + 1) objective evaluations (initial population + EG generations). Defaults NP = 60, EG = 1200
  (Liu 2021 §3.1).
* ``Result``: best ``x``, its value ``fun``, ``history`` (EG + 1,) best value after each generation (index 0 =
  initial population), ``nfev``.

The methods
-----------
* :func:`de_rand1` — DE/rand/1/bin: mutation eq. 11 (F = 1.2), binomial crossover eq. 12 (CR = 0.6), greedy
  selection eq. 13.
* :func:`de_current_to_best1` — DE/current-to-best/1 (eq. 14), same F, CR.
* :func:`de_integration` — the integration strategy alone: eq. 15 with the weight b(t) of eq. 16, fixed F.
* :func:`ide` — full IDE: eq. 18 = eq. 15 + b(t) of eq. 16 + adaptive F(t) of eq. 17 (alpha = 0.1, beta = 0.15).
* :func:`ga` — real-coded genetic algorithm (tournament, SBX, polynomial mutation, elitism).
* :func:`pso` — particle swarm (linearly decreasing inertia, c1, c2, velocity clamp).
* :func:`scipy_de` — ``scipy.optimize.differential_evolution`` on the same objective and budget (reference).
* :func:`lsq` — local least squares (``scipy.optimize.least_squares``, trf, x_scale from the bounds) from a
  random start (or ``x0``).
* :func:`ide_lsq` — IDE followed by a least-squares polish from IDE's best.

Choices the paper leaves open (documented defaults; fixed in config):

* Crossover (eq. 12) as written never forces a mutant component into the trial; we follow the usual
  Storn-Price rule and force one randomly chosen component (``force_one=True``); ``False`` is the literal eq. 12.
* Selection eq. 13 is strict: a trial replaces its parent only if it is strictly better.
* Trial components outside the bounds (``bound_mode``): ``'reinit'`` (default; redrawn uniformly within the
  bounds, as scipy does), ``'reflect'`` (mirrored at the violated bound), ``'clip'``, ``'midpoint'`` (halfway
  between the parent's value and the violated bound).
* Mutation indices: r1, r2, r3 distinct and different from the target i (needs NP >= 4).
* Eq. 16 is evaluated at t = 0 .. EG-1 (the generation being produced is t+1): b rises from 0 to ~1.
* Eq. 17: F(t) = F_max - (F_max - F_min) / (1 + alpha (1/f_min(t) - 1/f_max(t)) / l_scale + beta (1 - t/EG)),
  where 1/f_min - 1/f_max = L_worst(t) - L_best(t) is the spread of the population's objective values.
  The paper gives neither F_max nor F_min: defaults F_max = 1.2 (its initial F), F_min = 0.3.
  *Units of L enter through alpha*: the spread has the units of L, so alpha (L_worst - L_best) is dimensionless
  only with a unit; ``l_scale`` (default 1.0, i.e. L in the objective's own units: g^2 for L_a with g in
  standard g, (deg/h)^2 for L_g, dimensionless for the relative L_gm) divides the spread. With these units the
  alpha term is small next to beta once the population has contracted, and F(t) falls from
  ~F_max - (F_max - F_min)/1.15 at t = 0 (spread ~ 0) towards F_min; a huge spread (L in (count s-1)^2)
  pins F at F_max. ``l_scale='initial'`` uses the initial population's best L (a scale-free variant).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numba
import numpy as np

BOUND_MODES = {"reinit": 0, "reflect": 1, "clip": 2, "midpoint": 3}


@dataclass
class Result:
    """Outcome of one optimisation run."""

    x: np.ndarray
    fun: float
    history: np.ndarray
    nfev: int
    method: str
    nit: int = 0
    time_s: float = 0.0
    F_history: np.ndarray | None = None
    population: np.ndarray | None = None
    population_fun: np.ndarray | None = None
    message: str = ""
    on_bound: list = field(default_factory=list)
    extra: dict = field(default_factory=dict)


def parse_bounds(bounds):
    """(lower (D,), upper (D,)) float arrays from a *tuple* ``(lower, upper)`` of arrays, or from a list /
    array of D ``(lo, hi)`` pairs (shape (D, 2))."""
    if isinstance(bounds, tuple) and len(bounds) == 2:
        lo, hi = (np.atleast_1d(np.asarray(v, dtype=float)).copy() for v in bounds)
    else:
        arr = np.asarray(bounds, dtype=float)
        if arr.ndim != 2 or arr.shape[1] != 2:
            raise ValueError(f"bounds: expected a tuple (lower, upper) or (D, 2) pairs, got shape {arr.shape}")
        lo, hi = arr[:, 0].copy(), arr[:, 1].copy()
    if lo.shape != hi.shape or lo.ndim != 1:
        raise ValueError(f"bounds: lower {lo.shape} and upper {hi.shape} must be 1-D of equal length")
    if not np.all(np.isfinite(lo)) or not np.all(np.isfinite(hi)) or np.any(hi <= lo):
        bad = int(np.argmax(~(hi > lo)))
        raise ValueError(f"bounds: component {bad} has lower {lo[bad]} >= upper {hi[bad]} (or non-finite)")
    return lo, hi


def bound_hits(x, lo, hi, rtol=1e-4):
    """Indices of components of ``x`` within rtol x range of a bound."""
    r = hi - lo
    return [int(j) for j in np.flatnonzero((x - lo <= rtol * r) | (hi - x <= rtol * r))]


def _budget(budget):
    NP, EG = (int(budget[0]), int(budget[1]))
    if NP < 4 or EG < 1:
        raise ValueError(f"budget (NP, EG) = {budget}: need NP >= 4 and EG >= 1")
    return NP, EG


def _evaluate(objective, pop):
    f = np.asarray(objective(pop), dtype=float)
    if f.shape != (pop.shape[0],):
        raise ValueError(f"objective returned shape {f.shape} for a population of {pop.shape[0]}")
    return np.where(np.isfinite(f), f, np.inf)


# ---------------------------------------------------------------------------------------------------------
# DE family: one numba kernel builds the trial vectors of a generation from pre-drawn uniforms
# ---------------------------------------------------------------------------------------------------------
@numba.njit(cache=True)
def de_trial_vectors(pop, ibest, u, F, bw, CR, lo, hi, force_one, mode, out):
    """Trial vectors: mutation eq. 15 (bw = 0: eq. 11; bw = 1: eq. 14), crossover eq. 12, bound repair.

    u (NP, 4 + 2D) uniforms: 3 for the distinct indices, 1 for the forced component, D for crossover,
    D for the bound repair.
    """
    NP, D = pop.shape
    for i in range(NP):
        k1 = 1 + int(u[i, 0] * (NP - 1))
        k2 = 1 + int(u[i, 1] * (NP - 2))
        if k2 >= k1:
            k2 += 1
        k3 = 1 + int(u[i, 2] * (NP - 3))
        a = min(k1, k2)
        b = max(k1, k2)
        if k3 >= a:
            k3 += 1
        if k3 >= b:
            k3 += 1
        r1 = (i + k1) % NP
        r2 = (i + k2) % NP
        r3 = (i + k3) % NP
        jr = int(u[i, 3] * D)
        for j in range(D):
            pij = pop[i, j]
            if u[i, 4 + j] < CR or (force_one and j == jr):
                v = ((1.0 - bw) * pop[r1, j] + bw * (pij + F * (pop[ibest, j] - pij))
                     + F * (pop[r2, j] - pop[r3, j]))
                if v < lo[j] or v > hi[j]:
                    if mode == 0:
                        v = lo[j] + u[i, 4 + D + j] * (hi[j] - lo[j])
                    elif mode == 1:
                        if v < lo[j]:
                            v = 2.0 * lo[j] - v
                        else:
                            v = 2.0 * hi[j] - v
                        if v < lo[j] or v > hi[j]:
                            v = lo[j] + u[i, 4 + D + j] * (hi[j] - lo[j])
                    elif mode == 2:
                        v = min(max(v, lo[j]), hi[j])
                    else:
                        if v < lo[j]:
                            v = 0.5 * (pij + lo[j])
                        else:
                            v = 0.5 * (pij + hi[j])
                out[i, j] = v
            else:
                out[i, j] = pij


@numba.njit(cache=True)
def _k_select(pop, fit, trials, ft):
    """Greedy selection eq. 13 in place (a NaN trial never wins); returns (i_best, L_best, L_worst finite)."""
    NP, D = pop.shape
    for i in range(NP):
        if ft[i] < fit[i]:
            fit[i] = ft[i]
            for j in range(D):
                pop[i, j] = trials[i, j]
    ib = 0
    worst = -np.inf
    for i in range(NP):
        if fit[i] < fit[ib]:
            ib = i
        if np.isfinite(fit[i]) and fit[i] > worst:
            worst = fit[i]
    return ib, fit[ib], worst


def b_weight(t, EG):
    """Weight distribution factor b(t) of Liu 2021 eq. 16: 2 t / EG - (t / EG)^2."""
    s = t / EG
    return 2.0 * s - s * s


def F_adaptive(t, EG, L_worst, L_best, F_max=1.2, F_min=0.3, alpha=0.1, beta=0.15, l_scale=1.0):
    """Adaptive mutation factor F(t) of Liu 2021 eq. 17 with 1/f_min - 1/f_max = L_worst - L_best."""
    spread = (L_worst - L_best) / l_scale
    return F_max - (F_max - F_min) / (1.0 + alpha * spread + beta * (1.0 - t / EG))


def _de_core(objective, bounds, rng, budget, *, method, b_sched, F_const=1.2, CR=0.6, adaptive=False,
             F_max=1.2, F_min=0.3, alpha=0.1, beta=0.15, l_scale=1.0, force_one=True, bound_mode="reinit",
             init=None, callback=None):
    t0 = time.perf_counter()
    lo, hi = parse_bounds(bounds)
    NP, EG = _budget(budget)
    D = lo.size
    if bound_mode not in BOUND_MODES:
        raise ValueError(f"bound_mode must be one of {list(BOUND_MODES)}, got {bound_mode!r}")
    mode = BOUND_MODES[bound_mode]
    # eq. 9: alpha_j = LB_j + rand(0, 1) (UB_j - LB_j)
    pop = lo + rng.random((NP, D)) * (hi - lo) if init is None else np.array(init, dtype=float)
    if pop.shape != (NP, D):
        raise ValueError(f"init population has shape {pop.shape}, expected {(NP, D)}")
    fit = _evaluate(objective, pop)
    nfev = NP
    hist = np.empty(EG + 1)
    hist[0] = fit.min()
    Fh = np.empty(EG)
    trials = np.empty_like(pop)
    if isinstance(l_scale, str):
        if l_scale != "initial":
            raise ValueError("l_scale must be a positive number or 'initial'")
        l_scale = float(fit[np.isfinite(fit)].min()) if np.isfinite(fit).any() else 1.0
        l_scale = l_scale if l_scale > 0 else 1.0
    ibest = int(np.argmin(fit))
    fbest = fit[ibest]
    finite = fit[np.isfinite(fit)]
    fworst = finite.max() if finite.size else np.inf
    for t in range(EG):
        bw = b_sched(t, EG)
        if adaptive:
            F = F_adaptive(t, EG, fworst, fbest, F_max, F_min, alpha, beta, l_scale)
            if not np.isfinite(F):
                F = F_max
        else:
            F = F_const
        Fh[t] = F
        u = rng.random((NP, 4 + 2 * D))
        de_trial_vectors(pop, ibest, u, F, bw, CR, lo, hi, force_one, mode, trials)
        ft = np.asarray(objective(trials), dtype=np.float64)
        if ft.shape != (NP,):
            raise ValueError(f"objective returned shape {ft.shape} for a population of {NP}")
        nfev += NP
        ibest, fbest, fworst = _k_select(pop, fit, trials, ft)  # eq. 13 (strict); min L == max f = 1/L
        hist[t + 1] = fbest
        if callback is not None and callback(t + 1, pop, fit):
            hist = hist[: t + 2]
            Fh = Fh[: t + 1]
            break
    i = int(np.argmin(fit))
    return Result(x=pop[i].copy(), fun=float(fit[i]), history=hist, nfev=nfev, method=method, nit=len(hist) - 1,
                  time_s=time.perf_counter() - t0, F_history=Fh, population=pop, population_fun=fit,
                  on_bound=bound_hits(pop[i], lo, hi))


def de_rand1(objective, bounds, rng, budget=(60, 1200), *, F=1.2, CR=0.6, **opts) -> Result:
    """DE/rand/1/bin: theta_M = theta_x + F (theta_y - theta_z) (Liu 2021 eq. 11), crossover eq. 12,
    selection eq. 13; F = 1.2, CR = 0.6 (Liu 2021 §3.1)."""
    return _de_core(objective, bounds, rng, budget, method="de_rand1", b_sched=lambda t, EG: 0.0, F_const=F,
                    CR=CR, **opts)


def de_current_to_best1(objective, bounds, rng, budget=(60, 1200), *, F=1.2, CR=0.6, **opts) -> Result:
    """DE/current-to-best/1: theta_M = theta_i + F (theta_best - theta_i) + F (theta_x - theta_y)
    (Liu 2021 eq. 14)."""
    return _de_core(objective, bounds, rng, budget, method="de_current_to_best1", b_sched=lambda t, EG: 1.0,
                    F_const=F, CR=CR, **opts)


def de_integration(objective, bounds, rng, budget=(60, 1200), *, F=1.2, CR=0.6, **opts) -> Result:
    """Integration strategy alone: Liu 2021 eq. 15 with b(t) of eq. 16 and a fixed F."""
    return _de_core(objective, bounds, rng, budget, method="de_integration", b_sched=b_weight, F_const=F, CR=CR,
                    **opts)


def ide(objective, bounds, rng, budget=(60, 1200), *, CR=0.6, F_max=1.2, F_min=0.3, alpha=0.1, beta=0.15,
        l_scale=1.0, **opts) -> Result:
    """Improved DE of Liu 2021 §3.2: mutation eq. 18 (eq. 15 with b(t) of eq. 16 and F(t) of eq. 17),
    crossover eq. 12 (CR = 0.6), selection eq. 13. See the module docstring for F_max, F_min and l_scale."""
    return _de_core(objective, bounds, rng, budget, method="ide", b_sched=b_weight, CR=CR, adaptive=True,
                    F_max=F_max, F_min=F_min, alpha=alpha, beta=beta, l_scale=l_scale, **opts)


# ---------------------------------------------------------------------------------------------------------
# GA and PSO (Liu 2021 Table 5 competitors)
# ---------------------------------------------------------------------------------------------------------
def ga(objective, bounds, rng, budget=(60, 1200), *, tournament=2, p_crossover=0.9, eta_c=15.0,
       p_mutation=None, eta_m=20.0, n_elite=2, init=None) -> Result:
    """Real-coded GA: tournament selection (size ``tournament``), simulated binary crossover (SBX, index
    ``eta_c``, probability ``p_crossover`` per pair, each variable exchanged with probability 1/2),
    polynomial mutation (index ``eta_m``, probability ``p_mutation`` per variable, default 1/D), children
    clipped to the bounds, elitism (the ``n_elite`` best parents replace the worst children).
    Evaluations: NP per generation."""
    t0 = time.perf_counter()
    lo, hi = parse_bounds(bounds)
    NP, EG = _budget(budget)
    D = lo.size
    rngw = hi - lo
    pm = 1.0 / D if p_mutation is None else p_mutation
    pop = lo + rng.random((NP, D)) * rngw if init is None else np.array(init, dtype=float)
    fit = _evaluate(objective, pop)
    nfev = NP
    hist = np.empty(EG + 1)
    hist[0] = fit.min()
    half = (NP + 1) // 2
    for t in range(EG):
        cand = rng.integers(0, NP, size=(2 * half, tournament))
        win = cand[np.arange(2 * half), np.argmin(fit[cand], axis=1)]
        p1, p2 = pop[win[:half]], pop[win[half:]]
        # SBX
        u = rng.random((half, D))
        beta_ = np.where(u <= 0.5, (2.0 * u) ** (1.0 / (eta_c + 1.0)),
                         (1.0 / (2.0 * (1.0 - u))) ** (1.0 / (eta_c + 1.0)))
        do = (rng.random((half, 1)) < p_crossover) & (rng.random((half, D)) < 0.5)
        beta_ = np.where(do, beta_, 1.0)
        c1 = 0.5 * ((1.0 + beta_) * p1 + (1.0 - beta_) * p2)
        c2 = 0.5 * ((1.0 - beta_) * p1 + (1.0 + beta_) * p2)
        kids = np.concatenate([c1, c2])[:NP]
        # polynomial mutation
        um = rng.random((NP, D))
        mut = rng.random((NP, D)) < pm
        delta = np.where(um < 0.5, (2.0 * um) ** (1.0 / (eta_m + 1.0)) - 1.0,
                         1.0 - (2.0 * (1.0 - um)) ** (1.0 / (eta_m + 1.0)))
        kids = np.where(mut, kids + delta * rngw, kids)
        kids = np.clip(kids, lo, hi)
        fk = _evaluate(objective, kids)
        nfev += NP
        if n_elite > 0:
            elite = np.argsort(fit)[:n_elite]
            worst = np.argsort(fk)[NP - n_elite:]
            kids[worst] = pop[elite]
            fk[worst] = fit[elite]
        pop, fit = kids, fk
        hist[t + 1] = fit.min()
    i = int(np.argmin(fit))
    return Result(x=pop[i].copy(), fun=float(fit[i]), history=hist, nfev=nfev, method="ga", nit=EG,
                  time_s=time.perf_counter() - t0, population=pop, population_fun=fit,
                  on_bound=bound_hits(pop[i], lo, hi))


@dataclass
class Swarm:
    """Outcome of :func:`particle_swarm`: global best, personal bests, per-iteration history and trajectory."""
    gbest: np.ndarray
    gcost: float
    history: np.ndarray  # (G+1,) cost of the global best after each iteration (index 0: initial swarm)
    pbest: np.ndarray
    pcost: np.ndarray
    nfev: int
    trajectory: np.ndarray | None = None  # (G+1, P, D) positions, when asked for


def particle_swarm(cost, lo, hi, rng, P: int, G: int, *, c1: float, c2: float, vlim, inertia=(0.9, 0.4),
                   fixed_coefficients=None, init=None, init_velocity: str = "zero", zero_velocity_at_bound=False,
                   gbest_update: str = "strict", keep_trajectory=False, progress=None) -> Swarm:
    """The one particle-swarm loop of ``calib`` (Kennedy & Eberhart 1995; inertia weight of Shi & Eberhart 1998).

    v <- w v + c1 r1 (pbest - x) + c2 r2 (gbest - x)  (He 2019 eq. 16),  x <- clip(x + v, lo, hi)  (eq. 17),
    |v_j| <= ``vlim_j``. ``cost(X) -> (P,)`` is called once per iteration on the whole swarm (G + 1 calls).

    ``inertia``: (w_start, w_end), w falling linearly over the G iterations, or one number (constant).
    ``fixed_coefficients``: None draws r1, r2 ~ U(0, 1) per particle and dimension each iteration (one
    ``rng.random((2, P, D))`` call); a pair (r1, r2) fixes them (the "paper" variant of He 2019, no draws).
    ``init_velocity``: 'zero' or 'uniform' (U(-vlim, vlim), drawn after the positions).
    ``zero_velocity_at_bound``: zero the velocity components whose position was clipped.
    ``gbest_update``: 'strict' keeps the global best until a personal best is strictly lower; 'argmin' takes
    the personal best of lowest cost each iteration (first one on ties).
    """
    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    D = lo.size
    vlim = np.broadcast_to(np.asarray(vlim, dtype=float), (D,))
    x = lo + rng.random((P, D)) * (hi - lo) if init is None else np.array(init, dtype=float)
    v = np.zeros((P, D)) if init_velocity == "zero" else (2.0 * rng.random((P, D)) - 1.0) * vlim
    c = cost(x)
    pbest, pcost = x.copy(), c.copy()
    g = int(np.argmin(pcost))
    gbest, gcost = pbest[g].copy(), float(pcost[g])
    hist = np.empty(G + 1)
    hist[0] = gcost
    traj = [x.copy()] if keep_trajectory else None
    w_start, w_end = (inertia, inertia) if np.isscalar(inertia) else inertia
    for m in range(G):
        w = w_start + (w_end - w_start) * m / max(G - 1, 1)
        if fixed_coefficients is None:
            r1, r2 = rng.random((2, P, D))
        else:
            r1, r2 = fixed_coefficients
        v = w * v + c1 * r1 * (pbest - x) + c2 * r2 * (gbest - x)
        v = np.clip(v, -vlim, vlim)
        x = x + v
        if zero_velocity_at_bound:
            v[(x < lo) | (x > hi)] = 0.0
        x = np.clip(x, lo, hi)
        c = cost(x)
        better = c < pcost
        pbest[better], pcost[better] = x[better], c[better]
        g = int(np.argmin(pcost))
        if gbest_update == "argmin" or pcost[g] < gcost:
            gbest, gcost = pbest[g].copy(), float(pcost[g])
        hist[m + 1] = gcost
        if keep_trajectory:
            traj.append(x.copy())
        if progress is not None:
            progress(m + 1)
    return Swarm(gbest, gcost, hist, pbest, pcost, P * (G + 1), np.array(traj) if keep_trajectory else None)


def pso(objective, bounds, rng, budget=(60, 1200), *, w_start=0.9, w_end=0.4, c1=2.0, c2=2.0, v_max=0.2,
        init=None) -> Result:
    """Global-best PSO (Shi & Eberhart 1998) through :func:`particle_swarm`: r1, r2 ~ U(0,1) per particle and
    dimension, inertia w falling linearly from ``w_start`` to ``w_end``, |v_j| clamped to ``v_max`` x (range
    of dimension j), positions clipped to the bounds (the velocity component that hit a bound is zeroed).
    Initial velocities U(-v_max, v_max) x range. Evaluations: NP per iteration."""
    t0 = time.perf_counter()
    lo, hi = parse_bounds(bounds)
    NP, EG = _budget(budget)
    sw = particle_swarm(lambda X: _evaluate(objective, X), lo, hi, rng, NP, EG, c1=c1, c2=c2,
                        vlim=v_max * (hi - lo), inertia=(w_start, w_end), init=init, init_velocity="uniform",
                        zero_velocity_at_bound=True, gbest_update="argmin")
    return Result(x=sw.gbest.copy(), fun=sw.gcost, history=sw.history, nfev=sw.nfev, method="pso", nit=EG,
                  time_s=time.perf_counter() - t0, population=sw.pbest, population_fun=sw.pcost,
                  on_bound=bound_hits(sw.gbest, lo, hi))


# ---------------------------------------------------------------------------------------------------------
# scipy reference and least squares
# ---------------------------------------------------------------------------------------------------------
def scipy_de(objective, bounds, rng, budget=(60, 1200), *, strategy="best1bin", mutation=(0.5, 1.0),
             recombination=0.7, **kw) -> Result:
    """``scipy.optimize.differential_evolution`` with the same budget: an initial population of exactly NP
    uniform draws from ``rng`` (passed as ``init``), ``maxiter = EG``, ``polish=False``, ``tol = atol = 0``
    (runs all generations), vectorised evaluation with deferred updating, and ``rng`` seeded from ``rng``.
    Strategy, mutation (dithered) and recombination are scipy's defaults unless given."""
    from scipy.optimize import differential_evolution

    t0 = time.perf_counter()
    lo, hi = parse_bounds(bounds)
    NP, EG = _budget(budget)
    init = lo + rng.random((NP, lo.size)) * (hi - lo)
    hist = [float(np.min(_evaluate(objective, init)))]

    def cb(intermediate_result):
        hist.append(float(intermediate_result.fun))

    res = differential_evolution(lambda x: _evaluate(objective, np.ascontiguousarray(x.T)), list(zip(lo, hi)),
                                 strategy=strategy, maxiter=EG, init=init, mutation=mutation,
                                 recombination=recombination, polish=False, tol=0.0, atol=0.0,
                                 updating="deferred", vectorized=True, callback=cb,
                                 rng=np.random.default_rng(rng.integers(2**63)), **kw)
    # scipy counts calls of the vectorised function in res.nfev; report evaluations: NP x (generations + 1)
    return Result(x=np.asarray(res.x), fun=float(res.fun), history=np.array(hist), nfev=NP * (int(res.nit) + 1),
                  method="scipy_de", nit=int(res.nit), time_s=time.perf_counter() - t0, message=str(res.message),
                  on_bound=bound_hits(np.asarray(res.x), lo, hi))


def lsq(objective, bounds, rng=None, budget=None, *, x0=None, max_nfev=None, tol=1e-12) -> Result:
    """Local least squares on ``objective.residuals`` (scipy ``least_squares``, 'trf', bounds, analytic
    Jacobian if the objective has one, ``x_scale`` = bound ranges). Starts at ``x0`` or a uniform draw from
    ``rng`` within the bounds. ``history`` = [L(x0), L(x)]; ``budget`` only caps ``max_nfev`` (NP x EG)."""
    from scipy.optimize import least_squares

    t0 = time.perf_counter()
    lo, hi = parse_bounds(bounds)
    if x0 is None:
        if rng is None:
            raise ValueError("lsq needs x0 or an rng for a random start")
        x0 = lo + rng.random(lo.size) * (hi - lo)
    x0 = np.clip(np.asarray(x0, dtype=float), lo, hi)
    if max_nfev is None and budget is not None:
        max_nfev = int(budget[0]) * int(budget[1])
    jac = getattr(objective, "jacobian", None) or "2-point"
    f0 = float(objective(x0))
    res = least_squares(objective.residuals, x0, jac=jac, bounds=(lo, hi), x_scale=hi - lo, method="trf",
                        xtol=tol, ftol=tol, gtol=tol, max_nfev=max_nfev)
    fx = float(objective(res.x))
    return Result(x=res.x, fun=fx, history=np.array([f0, fx]), nfev=int(res.nfev), method="lsq",
                  nit=int(res.nfev), time_s=time.perf_counter() - t0, message=str(res.message),
                  on_bound=[int(j) for j in np.flatnonzero(res.active_mask != 0)] or bound_hits(res.x, lo, hi, 1e-9),
                  extra={"njev": int(res.njev) if res.njev is not None else 0, "status": int(res.status)})


def ide_lsq(objective, bounds, rng, budget=(60, 1200), *, lsq_opts=None, **ide_opts) -> Result:
    """IDE (:func:`ide`) followed by a least-squares polish (:func:`lsq`) from IDE's best vector.
    The polish is kept only if it does not increase the objective."""
    t0 = time.perf_counter()
    r1 = ide(objective, bounds, rng, budget, **ide_opts)
    r2 = lsq(objective, bounds, x0=r1.x, **(lsq_opts or {}))
    best = r2 if r2.fun <= r1.fun else r1
    return Result(x=best.x.copy(), fun=best.fun, history=np.concatenate([r1.history, [best.fun]]),
                  nfev=r1.nfev + r2.nfev, method="ide_lsq", nit=r1.nit, time_s=time.perf_counter() - t0,
                  F_history=r1.F_history, population=r1.population, population_fun=r1.population_fun,
                  message=r2.message, on_bound=best.on_bound,
                  extra={"ide_fun": r1.fun, "ide_x": r1.x, "polish_nfev": r2.nfev, **r2.extra})


METHODS = {
    "de_rand1": de_rand1,
    "de_current_to_best1": de_current_to_best1,
    "de_integration": de_integration,
    "ide": ide,
    "ga": ga,
    "pso": pso,
    "scipy_de": scipy_de,
    "lsq": lsq,
    "ide_lsq": ide_lsq,
}


def minimize(method: str, objective, bounds, rng, budget=(60, 1200), **opts) -> Result:
    """Dispatch to one of :data:`METHODS` by name (same signature as the methods themselves)."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; one of {', '.join(METHODS)}")
    return METHODS[method](objective, bounds, rng, budget, **opts)
