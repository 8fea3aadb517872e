"""Is V = zᵀPz a control Lyapunov function for the identified model?  Checked, never assumed.

1. **Globally** (the paper's Proposition 1, for the homogeneous part ż = Λz + uBz as in the paper): V is a CLF
   iff no z ≠ 0 has zᵀQ_Λz ≥ 0 and zᵀQ_{B}z = 0.  By Finsler's lemma this holds iff
   min_μ λ_max(Q_Λ + Σ μ_i Q_{B_i}) < 0 (exact for m = 1; sufficient for m > 1), solved as a small SDP.
2. **On the data manifold** z = Ψ(x) over a grid of x in the region of interest (the model's own V̇, the affine
   b_i included): where L_ΛV ≥ 0, how small |L_BV| gets, and the decay rate V̇/V achieved by h.
3. **Level sets** by sampling: r = the largest level such that every sampled x with V < r lies inside the region
   and has V̇(h) < 0; r̂ = the largest level of sampled states in Ω_r where one sample-and-hold step of h fails to
   decrease V (at least ``rhat_floor``·r), so that outside Ω_r̂ the held input decreases V.
4. **V bounds the state** (:mod:`kexp.clf.bound`): V ≥ c‖x − x_eq‖² over the sampled states, the direction
   where V is flattest, and the gain γ of the bound in the region's scale; with γ > 20 a decrease of V does not
   keep the state in the region and the verdict is "not a CLF in x", whatever the decrease.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError
from .bound import GAIN_MAX, state_bound


@dataclass(frozen=True)
class CertificateReport:
    """The result of :func:`check_certificate` (frozen): Proposition 1's verdict and Finsler margin
    (``global_holds``, ``global_margin`` < 0 holds, the multipliers ``global_mu`` (m,)), what the sampled states
    of the region show (fractions in [0, 1], the decay rate V̇/V in 1/s) and the levels ``r`` ≥ ``r_hat`` > 0 of
    Ω_r and Ω_r̂.  ``verdict`` is one sentence, ``lines()`` the printed summary, ``to_dict()`` a JSON-ready dict
    (with the verdict; ``global_mu`` as a list)."""

    global_holds: bool
    global_margin: float          # min_μ λ_max(Q_Λ + Σμ_i Q_Bi) / ‖Q_Λ‖ (< 0: holds)
    global_mu: tuple[float, ...]
    n_samples: int
    frac_drift_nonneg: float      # sampled x with L_ΛV ≥ 0
    min_rel_lbv_where_drift_nonneg: float  # min ‖L_BV‖ / V over those
    frac_decrease: float          # sampled x where V̇(h) < 0
    decay_median: float           # median V̇/V under h (1/s)
    decay_worst: float            # max V̇/V under h
    holds_on_samples: bool
    r: float
    r_hat: float
    frac_in_omega_r: float        # sampled x inside Ω_r
    frac_sh_fail: float           # sampled x in Ω_r where one held step of h does not decrease V
    c_x: float                    # min V(x)/‖x − x_eq‖² over the sampled x
    flat_direction: tuple[float, ...]         # unit (x − x_eq)/‖x − x_eq‖ at that minimiser
    c_local: float                # λ_min(JᵀPJ), J = ∂z/∂x(x_eq)
    flat_direction_local: tuple[float, ...]   # its unit eigenvector
    bound_gain: float             # γ: a decrease of V keeps x̃ within γ·|x̃0| (region-scaled x − x_eq)
    bounds_state: bool            # γ ≤ GAIN_MAX

    @property
    def verdict(self) -> str:
        if not self.bounds_state:
            return (f"not a CLF in x: V is nearly blind to the state along {_vec(self.flat_direction)} "
                    f"(V ≥ c‖x − x_eq‖² only with c = {self.c_x:.3g}), so a decrease of V does not keep the state "
                    f"in the region (bound gain {self.bound_gain:.3g} > {GAIN_MAX:g}), whatever the decrease")
        if self.global_holds:
            return "V is a CLF of the homogeneous model (Proposition 1 holds)"
        if self.holds_on_samples:
            return "Proposition 1 FAILS globally, but h decreases V at every sampled state of the region"
        return "NOT a certified CLF: Proposition 1 fails and h does not decrease V everywhere in the region"

    def lines(self) -> list[str]:
        return [f"certificate: {self.verdict}",
                f"  Proposition 1 (Finsler): margin {self.global_margin:+.3e} (< 0 holds), μ = "
                f"{', '.join(f'{m:.3g}' for m in self.global_mu)}",
                f"  on z = Ψ(x), {self.n_samples} sampled x: L_ΛV ≥ 0 at {self.frac_drift_nonneg:.1%}, "
                f"min |L_BV|/V there {self.min_rel_lbv_where_drift_nonneg:.3g}; V̇(h) < 0 at {self.frac_decrease:.1%}; "
                f"V̇/V median {self.decay_median:.3g}, worst {self.decay_worst:.3g} 1/s",
                f"  level sets: r = {self.r:.4g} (Ω_r holds {self.frac_in_omega_r:.1%} of the samples), "
                f"r̂ = {self.r_hat:.4g}; held-input decrease fails at {self.frac_sh_fail:.1%} of Ω_r",
                f"  V bounds x: V ≥ c‖x − x_eq‖², c = {self.c_x:.4g} (flattest along {_vec(self.flat_direction)}); "
                f"at x_eq λ_min(JᵀPJ) = {self.c_local:.4g} along {_vec(self.flat_direction_local)}; a decrease of V "
                f"keeps x within {self.bound_gain:.3g}× its start (region-scaled), "
                + ("≤ {:g}: V bounds the state".format(GAIN_MAX) if self.bounds_state
                   else "> {:g}: not a CLF in x".format(GAIN_MAX))]

    def to_dict(self) -> dict:
        from dataclasses import asdict
        d = asdict(self)
        for key in ("global_mu", "flat_direction", "flat_direction_local"):
            d[key] = list(getattr(self, key))
        d["verdict"] = self.verdict
        return d


def _vec(v) -> str:
    return "(" + ", ".join(f"{a:.3g}" for a in v) + ")"


FINSLER_SDP_MAX_K = 40   # up to this k the margin is the small SDP's; above, the eigenvalue search (_finsler_eig)
LONG_K = 30              # from this k the CLF's stages announce themselves (the built-in presets have k ≤ 21)


def finsler_margin(lyap) -> tuple[float, tuple[float, ...]]:
    """min_μ λ_max(Q_Λ + Σ μ_i Q_{B_i}) / ‖Q_Λ‖₂ and the minimiser μ, the value clipped below at −1 (the margin
    then says "holds" whatever its size).  For k ≤ :data:`FINSLER_SDP_MAX_K` a small SDP (CLARABEL, as always);
    above it the SDP's KKT system, dense in the k(k+1)/2 entries of the LMI, costs minutes (101 s at k = 125
    measured, growing as k⁶), so the convex function μ ↦ λ_max is minimised directly (:func:`_finsler_eig`: one
    k×k eigendecomposition per evaluation, ~0.3 s at k = 125).  Either way λ_max is re-evaluated at the μ found,
    so the margin is an upper bound of the minimum (exact to the search's tolerance for m = 1): a negative margin
    proves Proposition 1.  Where CLARABEL fails on the small SDP (SolverError), the search gives the margin."""
    if lyap.Q_lam.shape[0] > FINSLER_SDP_MAX_K:
        return _finsler_eig(lyap)
    return _finsler_sdp(lyap)


def _finsler_sdp(lyap) -> tuple[float, tuple[float, ...]]:
    """:func:`finsler_margin` by the SDP min t s.t. tI ⪰ Q_Λ + Σμ_i Q_Bi (scaled), t ≥ −1 (CLARABEL)."""
    import cvxpy as cp
    q_lam = lyap.Q_lam
    scale = max(np.linalg.norm(q_lam, 2), 1e-300)
    m = lyap.m
    mu = cp.Variable(m)
    t = cp.Variable()
    expr = q_lam / scale + sum(mu[i] * lyap.Q_b[i] / scale for i in range(m))
    expr = 0.5 * (expr + expr.T)
    # t ≥ −1 keeps the problem bounded when the condition holds (then Q_B can push λ_max down without end)
    prob = cp.Problem(cp.Minimize(t), [t * np.eye(q_lam.shape[0]) - expr >> 0, t >= -1.0])
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # 'optimal_inaccurate' is fine: λ_max is re-evaluated below
        try:
            prob.solve(solver="CLARABEL")
        except cp.error.SolverError:   # seen on the cart-pole's SDP CLF (k = 34): the search needs no solver
            return _finsler_eig(lyap)
    if prob.status not in ("optimal", "optimal_inaccurate") or mu.value is None:
        return float("nan"), (float("nan"),) * m
    mu_v = np.asarray(mu.value, dtype=float)
    # evaluate the exact λ_max at the minimiser (independent of the solver's accuracy)
    mat = q_lam / scale + np.einsum("i,ijk->jk", mu_v, lyap.Q_b / scale)
    lmax = float(np.linalg.eigvalsh(0.5 * (mat + mat.T))[-1])
    return lmax, tuple(float(v) for v in mu_v * 1.0)


def _finsler_eig(lyap, sweeps: int = 20) -> tuple[float, tuple[float, ...]]:
    """:func:`finsler_margin` without an SDP: f(μ) = λ_max(A + Σ μ_i B_i) (A = Q_Λ/‖Q_Λ‖₂, B_i = Q_Bi/‖Q_Λ‖₂,
    symmetrised) is convex, and vᵀB_i v (v a unit eigenvector of λ_max) is a subgradient's i-th entry, so along
    one coordinate the minimiser is bracketed (steps growing ×4 from 1) and bisected on the subgradient's sign to
    a relative width of 1e-13.  One input: that is the minimum.  Several: cyclic coordinate descent, up to
    ``sweeps`` sweeps (a nonsmooth convex function can stall there: the value is an upper bound).  Stops as
    soon as f ≤ −1 (the SDP's t ≥ −1)."""
    q_lam = lyap.Q_lam
    scale = max(np.linalg.norm(q_lam, 2), 1e-300)
    A = 0.5 * (q_lam + q_lam.T) / scale
    Bs = [0.5 * (b + b.T) / scale for b in lyap.Q_b]
    m = len(Bs)
    mu = np.zeros(m)

    def top(v):
        mat = A + np.einsum("i,ijk->jk", v, np.asarray(Bs)) if m else A
        w, vec = np.linalg.eigh(mat)
        return float(w[-1]), vec[:, -1]

    def line(v, i):
        """Minimise f along coordinate i from v: (f, μ_i)."""
        def at(x):
            trial = v.copy()
            trial[i] = x
            f, vec = top(trial)
            return f, float(vec @ Bs[i] @ vec)
        x0 = v[i]
        f0, d0 = at(x0)
        best = (f0, x0)
        if d0 == 0.0 or f0 <= -1.0:
            return best
        sgn = -np.sign(d0)
        lo, step = x0, 1.0
        hi = x0 + sgn * step
        while True:
            f, d = at(hi)
            if f < best[0]:
                best = (f, hi)
            if f <= -1.0 or np.sign(d) != -sgn or abs(hi) > 1e15:
                break
            lo, step = hi, step * 4.0
            hi = x0 + sgn * step
        if f <= -1.0 or abs(hi) > 1e15 or d == 0.0:
            return best
        for _ in range(200):                   # the minimiser lies between lo (slope towards hi) and hi
            if abs(hi - lo) <= 1e-13 * max(1.0, abs(lo), abs(hi)):
                break
            mid = 0.5 * (lo + hi)
            f, d = at(mid)
            if f < best[0]:
                best = (f, mid)
            if f <= -1.0 or d == 0.0:
                break
            if np.sign(d) == -sgn:             # still descending towards hi
                lo = mid
            else:
                hi = mid
        return best

    f = top(mu)[0]
    for _ in range(sweeps if m > 1 else 1):
        before = f
        for i in range(m):
            f, mu[i] = line(mu, i)
        if f <= -1.0 or before - f <= 1e-12 * max(1.0, abs(f)):
            break
    return top(mu)[0], tuple(float(v) for v in mu)


def _region_values(value, key: str) -> np.ndarray | None:
    """``value`` as a 1-D float array (a number gives shape ()), or None when it is not a finite number or a
    non-empty sequence of finite numbers."""
    if isinstance(value, (str, bytes, bool)) or value is None:
        return None
    try:
        raw = np.asarray(value)
    except ValueError:       # a ragged list
        return None
    if raw.dtype.kind not in "iuf" or raw.ndim > 1 or raw.size == 0:
        return None
    a = raw.astype(float)
    return a if np.all(np.isfinite(a)) else None


def check_region_config(low, high) -> None:
    """ClfConfig's ``region_low``/``region_high``: each a finite number or a sequence of finite numbers (one per
    state), sequences of one length, low < high in every coordinate.  Raises ConfigError naming clf.<key>."""
    lo, hi = _region_values(low, "clf.region_low"), _region_values(high, "clf.region_high")
    for key, value, arr in (("region_low", low, lo), ("region_high", high, hi)):
        if arr is None:
            raise ConfigError(f"clf.{key}={value!r}: give a finite number or one finite number per state "
                              "(the certificate's box of x − x_eq)")
    if lo.ndim and hi.ndim and lo.size != hi.size:
        raise ConfigError(f"clf.region_low={low!r}, clf.region_high={high!r}: give both with one number per state "
                          "(the same length), or a single number")
    if not np.all(lo < hi):
        raise ConfigError(f"clf.region_low={low!r}, clf.region_high={high!r}: need region_low < region_high in "
                          "every coordinate")
    if not (np.all(lo <= 0) and np.all(hi >= 0)):
        raise ConfigError(f"clf.region_low={low!r}, clf.region_high={high!r}: the box of x − x_eq must hold the "
                          "equilibrium: need region_low <= 0 <= region_high in every coordinate")


def certificate_bytes(n_samples: int, n: int, k: int, m: int) -> int:
    """An upper estimate of the bytes check_certificate holds at once for ``n_samples`` states: the lifted z, V,
    the Lie derivatives, u and the held step's RK4 stages.  Measured peaks (tracemalloc, Van der Pol, 90601
    states): 437, 979 and 1168 bytes per state for k = 9, 20 and 35; the estimate gives 768, 1296 and 2016."""
    return 8 * n_samples * (6 * k + 8 * n + 6 * m + 20)


def n_samples(n: int, grid: int) -> int:
    """The number of sampled states of :func:`region_grid`: grid**n for n ≤ 3, else 20000."""
    return grid ** n if n <= 3 else 20000


def check_region(model, config) -> None:
    """The region of ``config`` (a ClfConfig) for ``model``: a sequence region_low/region_high must have one number
    per state (n), and the sampled states must fit the memory budget (``$KEXP_MEMORY_BUDGET_GB``, 4 GB by
    default).  Raises ConfigError naming clf.<key> and what to change."""
    from ..control.memory import memory_budget
    n = model.n
    for key in ("region_low", "region_high"):
        arr = _region_values(getattr(config, key), f"clf.{key}")
        if arr is not None and arr.ndim and arr.size != n:
            raise ConfigError(f"clf.{key}={getattr(config, key)!r} has {arr.size} value(s); the model has n={n} "
                              f"state(s): give {n} numbers or a single number")
    count = n_samples(n, config.grid)
    need, budget = certificate_bytes(count, n, model.k, model.m), memory_budget()
    if need > budget:
        raise ConfigError(f"clf.grid={config.grid} samples {count:.3g} states for n={n} (grid**n), about "
                          f"{need / 1e9:.3g} GB, over the budget of {budget / 1e9:.3g} GB (KEXP_MEMORY_BUDGET_GB): "
                          "lower clf.grid (default 41)")


def region_grid(x_eq: np.ndarray, low, high, grid: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Sample states: a full grid for n ≤ 3, else 20000 uniform points.  Returns (x (M, n), on_boundary (M,))."""
    n = x_eq.size
    lo = np.broadcast_to(np.asarray(low, dtype=float), (n,))
    hi = np.broadcast_to(np.asarray(high, dtype=float), (n,))
    if n <= 3:
        axes = [np.linspace(a, b, grid) for a, b in zip(lo, hi)]
        pts = np.array(list(itertools.product(*axes)))
    else:
        pts = np.random.default_rng(seed).uniform(lo, hi, (20000, n))
    tol = 1e-12 * np.maximum(1.0, np.abs(hi - lo))
    boundary = np.any((np.abs(pts - lo) <= tol) | (np.abs(pts - hi) <= tol), axis=1)
    return x_eq + pts, boundary


def sampled_states(model, config) -> tuple[np.ndarray, np.ndarray]:
    """The states the certificate samples (:func:`region_grid` of ``config``'s region around x_eq, without those
    within 1e-3 of the region's size from x_eq): (x (M, n), on_boundary (M,))."""
    x, boundary = region_grid(model.x_eq, config.region_low, config.region_high, config.grid)
    radius = np.max(np.abs(np.asarray(config.region_high, dtype=float) - np.asarray(config.region_low, dtype=float)))
    keep = np.linalg.norm(x - model.x_eq, axis=1) > 1e-3 * radius
    return x[keep], boundary[keep]


def check_certificate(model, lyap, law, config, progress=None) -> CertificateReport:
    """Check V = zᵀPz (``lyap``, a :class:`~kexp.clf.QuadraticLyapunov`) for the identified ``model`` and the
    explicit law ``law`` (z (M, k) -> u (M, m)): Proposition 1 by a small SDP (CLARABEL), then the model's own V̇
    under ``law`` on a grid of ``config.grid`` points per axis over the box ``config.region_low`` ..
    ``region_high`` around x_eq (20000 uniform points for n > 3), and the levels r and r̂ (see the module text).
    ``config`` is a :class:`~kexp.clf.ClfConfig`.  Returns a :class:`CertificateReport`; never raises on a failed
    certificate (it is a verdict, not an error).  ``progress`` (a callable taking one line, or None) is told what
    is being done when the model is large (k ≥ :data:`LONG_K`)."""
    check_region(model, config)
    count = n_samples(model.n, config.grid)
    if progress is not None and model.k >= LONG_K:
        how = "an SDP" if model.k <= FINSLER_SDP_MAX_K else "an eigenvalue search"
        sampled = f"a grid of {config.grid}^{model.n}" if model.n <= 3 else "uniform samples of the region"
        progress(f"certificate: Proposition 1 on k = {model.k} coordinates ({how}), then V̇ at {count} sampled "
                 f"states ({sampled})…")
    margin, mu = finsler_margin(lyap)
    x, boundary = sampled_states(model, config)
    z = model.lift(x)
    V = lyap.value(z)
    a, beta = lyap.lie(z)
    u = law(z)
    vdot = a + np.sum(beta * u, axis=1)
    rate = vdot / np.maximum(V, 1e-300)
    drift_nonneg = a >= 0
    rel_lbv = np.linalg.norm(beta, axis=1) / np.maximum(V, 1e-300)
    bad = vdot >= 0
    r_candidates = [V[boundary].min() if boundary.any() else np.inf, V[bad].min() if bad.any() else np.inf]
    r = float(min(r_candidates))
    if not np.isfinite(r):
        r = float(V.max())
    inside = V < r
    # one sample-and-hold step of h on the model, for states in Ω_r
    r_hat = config.rhat_floor * r
    frac_fail = 0.0
    if inside.any():
        zi = z[inside]
        vplus = lyap.value(model.step_batch(zi, u[inside]))
        fail = vplus >= V[inside]
        frac_fail = float(fail.mean())
        if fail.any():
            r_hat = max(r_hat, float(V[inside][fail].max()))
        r_hat = min(r_hat, r)
    bound = state_bound(model, lyap, x, V, config.region_low, config.region_high)
    return CertificateReport(
        global_holds=bool(np.isfinite(margin) and margin < 0), global_margin=float(margin), global_mu=mu,
        n_samples=int(x.shape[0]), frac_drift_nonneg=float(drift_nonneg.mean()),
        min_rel_lbv_where_drift_nonneg=float(rel_lbv[drift_nonneg].min()) if drift_nonneg.any() else float("nan"),
        frac_decrease=float((~bad).mean()), decay_median=float(np.median(rate)), decay_worst=float(rate.max()),
        holds_on_samples=bool(not bad.any()), r=r, r_hat=float(r_hat), frac_in_omega_r=float(inside.mean()),
        frac_sh_fail=frac_fail, c_x=bound.c, flat_direction=bound.direction, c_local=bound.c_local,
        flat_direction_local=bound.direction_local, bound_gain=bound.gain, bounds_state=bound.holds)
