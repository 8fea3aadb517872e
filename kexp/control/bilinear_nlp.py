"""The bilinear Koopman model as a CasADi step map and the LMPC's NLP on it, solved to convergence by CasADi + IPOPT:
:class:`IpoptLmpc`, a reference ("oracle") controller with the step interface of :class:`~kexp.control.lmpc.Lmpc`
(``name``, ``reset()``, ``step(x0, z0) -> ControlStep``).  It solves the SAME problem as :class:`Lmpc` (paper eq. 21
on the bilinear Koopman model: same cost incl. ``state_cost`` 'z'/'x' and ``terminal``, same move blocking, same slack
penalty ρ(s + s²), the same (21e)/(21f) switching by region, the same input bounds) as a multiple-shooting NLP, to
check kexp's SQP.  The IPOPT plumbing here (:func:`_casadi`, :func:`_ipopt_options`, :func:`_solve`)
and :func:`rk4_step` are also used by the true-model oracle, :class:`~kexp.control.oracle.NmpcOracle`.

Discretisation of the bilinear model.  ``discretisation='exact'``: for the held input u the model is
linear, ż = A_u z + c_u, and one step is expm([[A_u, c_u], [0, 0]]Δ)·[z; 1], evaluated symbolically as its Taylor
series applied to the vector [z; 1] (q substeps of Δ/q, p terms).  q and p are chosen from an upper bound θ of
‖[[A_u, c_u], [0, 0]]Δ‖_∞ over the input box (θ/q ≤ 0.5 and (θ/q)^{p+1}/(p+1)!·e^{θ/q} ≤ 2⁻⁵⁶), so the truncation is
below rounding — the same construction as kexp's numba kernel (``expm_kernels.expm_small``, Taylor to 1e-16); CasADi's
own ``expm`` needs the SLICOT plugin, which the pip wheel lacks.  ``discretisation='rk4'`` uses classical RK4 with
``substeps`` (default 8) per Δ.  Measured on the Van der Pol test model (Monomials(2, 3), k = 9, Δ = 0.01,
|u| ≤ 5, 20 steps, 200 random z0 = Ψ(x0) − Ψ(0) with x0 ∈ [−1, 1]² and random inputs in [−5, 5]):
max |z_casadi − z_kexp| = 4.9e-15 (2.3e-15 relative) for 'exact' (θ = 0.29: q = 1, p = 13), 1.8e-11 for 'rk4'
with 8 substeps (2.7e-10 with 4, 7.0e-8 with 1).  'exact' is also the cheaper one (13 matrix-vector products per
step against RK4's 32).  ``discretisation='polynomial'`` (one input; chosen by the default 'auto') is the same exact
map with its terms regrouped as a polynomial in u, which keeps CasADi's derivatives small enough for horizon 100
(see :func:`bilinear_step_function`).

IPOPT runs with ``print_level 0``, no banner, exact Hessian and ``bound_relax_factor 0`` (so s ≥ 0 and the input
bounds hold exactly and IPOPT's objective is the problem's, not a relaxed one's).  The NLP is built once per
controller and reused with new parameters / bounds each step, warm-started from the previous solution shifted by one
step.  A solve that does not
end in 'Solve_Succeeded' or 'Solved_To_Acceptable_Level' (or raises, or returns non-finite numbers) falls back to
the explicit law h(z_0) and says why; :meth:`step` never raises on a solver failure.

``ControlStep`` fields: ``qp_status`` is IPOPT's return status string, ``iterations`` IPOPT's iteration count, and
``qp_iterations`` the same number (each IPOPT iteration is one factorisation of an interior-point KKT system, the
unit the LMPC's QP iteration count also measures).  ``solve_time`` is the wall time of the whole step.

casadi is optional (``pip install casadi``, the extra ``kexp[oracle]``): it is imported only by :func:`_casadi`, on
first use.
"""
from __future__ import annotations

import math
import time

import numpy as np

from ..errors import ConfigError
from .blocking import block_of_step, block_sizes
from .checks import check_model_parts, input_bounds
from .kernels import rollout
from .lmpc import ControlStep, LmpcConfig, lyapunov_context

IPOPT_OK = ("Solve_Succeeded", "Solved_To_Acceptable_Level")
DISCRETISATIONS = ("auto", "exact", "polynomial", "rk4")


def _casadi():
    try:
        import casadi
    except ImportError:  # pragma: no cover - depends on the environment
        raise ConfigError("the IPOPT oracle controllers need casadi, which is not installed: pip install casadi "
                          "(or the extra: pip install 'kexp[oracle]')") from None
    return casadi


def _ipopt_options(tol: float, max_iter: int, extra: dict | None) -> dict:
    if not (tol > 0 and max_iter >= 1):
        raise ConfigError(f"ipopt tol={tol}, max_iter={max_iter}: need tol > 0 and max_iter >= 1")
    opts = {"ipopt.print_level": 0, "print_time": 0, "ipopt.sb": "yes", "ipopt.tol": float(tol),
            "ipopt.max_iter": int(max_iter), "ipopt.bound_relax_factor": 0.0, "error_on_fail": False}
    opts.update(extra or {})
    return opts


def _solve(solver, args: dict):
    """Run the nlpsol; returns (solution dict | None, status, iterations, why)."""
    try:
        sol = solver(**args)
        stats = solver.stats()
    except Exception as exc:  # noqa: BLE001 - a solver failure must never escape step()
        first = str(exc).splitlines()[0] if str(exc) else ""
        return None, "exception", 0, f"IPOPT raised {type(exc).__name__}: {first}"
    status = str(stats.get("return_status", "unknown"))
    iters = int(stats.get("iter_count", 0))
    if status not in IPOPT_OK:
        return None, status, iters, f"IPOPT: {status}"
    x = np.asarray(sol["x"], float).reshape(-1)
    if not np.all(np.isfinite(x)):
        return None, status, iters, "IPOPT returned non-finite values"
    return sol, status, iters, ""


# ---- discretisations (symbolic) ----------------------------------------------------------------------------------
def taylor_terms(theta: float) -> tuple[int, int]:
    """(q substeps, p Taylor terms) with θ/q ≤ 0.5 and (θ/q)^{p+1}/(p+1)!·e^{θ/q} ≤ 2⁻⁵⁶."""
    q = max(1, int(math.ceil(theta / 0.5)))
    t = theta / q
    p = 1
    while p < 40 and t ** (p + 1) / math.factorial(p + 1) * math.exp(t) > 2.0 ** -56:
        p += 1
    return q, p


def bilinear_step_exact(ca, lam, B, b, dt, z, u, q: int, p: int):
    """Symbolic exact zero-order-hold step of ż = (Λ + Σu_iB_i)z + Σu_ib_i over dt: the Taylor series of
    expm([[A_u, c_u], [0, 0]]h)·[z; 1] with q substeps h = dt/q and p terms (see the module docstring)."""
    h = dt / q
    A = ca.DM(lam * h)
    for i in range(B.shape[0]):
        A = A + u[i] * ca.DM(B[i] * h)
    c = 0
    for i in range(B.shape[0]):
        c = c + u[i] * ca.DM(b[i] * h)
    for _ in range(q):
        t = ca.mtimes(A, z) + c          # first-order term; the augmented '1' only enters here
        acc = z + t
        for j in range(2, p + 1):
            t = ca.mtimes(A, t) / j
            acc = acc + t
        z = acc
    return z


def rk4_step(f, x, u, dt, substeps: int):
    """Classical RK4 with ``substeps`` for ẋ = f(x, u), u held over dt."""
    h = dt / substeps
    for _ in range(substeps):
        k1 = f(x, u)
        k2 = f(x + 0.5 * h * k1, u)
        k3 = f(x + 0.5 * h * k2, u)
        k4 = f(x + h * k3, u)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


def step_polynomial(lam, B, b, dt: float, q: int, p: int) -> np.ndarray:
    """Coefficients C (D+1, k+1, k+1), D = q·p, of the exact step for a single input as a polynomial in u:
    T(u)^q [z; 1] = Σ_d u^d C_d [z; 1], T(u) = Σ_{j≤p} (A₀ + uA₁)^j / j!, A₀ = [[Λ, 0], [0, 0]]·Δ/q,
    A₁ = [[B, b], [0, 0]]·Δ/q — the same map as :func:`bilinear_step_exact` with (q, p), its terms regrouped."""
    lam, B, b = np.asarray(lam, float), np.asarray(B, float), np.asarray(b, float)
    k = lam.shape[0]
    if B.shape[0] != 1:
        raise ConfigError(f"the polynomial step form is for one input; this model has m = {B.shape[0]} "
                          "(use discretisation='exact')")
    h = dt / q
    A0 = np.zeros((k + 1, k + 1))
    A0[:k, :k] = lam * h
    A1 = np.zeros((k + 1, k + 1))
    A1[:k, :k] = B[0] * h
    A1[:k, k] = b[0] * h
    power = np.zeros((p + 1, k + 1, k + 1))   # coefficients of (A₀ + uA₁)^j in u
    power[0] = np.eye(k + 1)
    T = power.copy()
    for j in range(1, p + 1):
        new = np.zeros_like(power)
        new[: j + 1] = power[: j + 1] @ A0
        new[1: j + 1] += power[:j] @ A1
        power = new
        T += power / math.factorial(j)
    C = T.copy()
    for _ in range(q - 1):                     # the q substeps: T(u)·(T(u)^s)
        out = np.zeros((C.shape[0] + p, k + 1, k + 1))
        for a in range(C.shape[0]):
            for c in range(p + 1):
                out[a + c] += T[c] @ C[a]
        C = out
    return C


def polynomial_terms(C: np.ndarray, umax: float, trunc: float = 1e-18) -> int:
    """How many leading terms of Σ_d u^d C_d to keep: the trailing ones with max|C_d|·umax^d < trunc·max|C_0|
    change the map by less than rounding."""
    size = np.array([np.abs(Cd).max() * umax ** d for d, Cd in enumerate(C)])
    return int(np.max(np.flatnonzero(size >= trunc * size[0]))) + 1


def _step_order(model, u_min, u_max, substeps):
    """(q, p) of the exact step for the input box (module docstring)."""
    lam, B, b, m = np.asarray(model.Lambda), np.asarray(model.B), np.asarray(model.b), model.m
    lo, hi = input_bounds(u_min, u_max, m)
    umax = np.maximum(np.abs(lo), np.abs(hi))
    rows = np.abs(lam).sum(axis=1) + sum(umax[i] * (np.abs(B[i]).sum(axis=1) + np.abs(b[i])) for i in range(m))
    q, p = taylor_terms(float(rows.max()) * float(model.dt))
    if substeps is not None:
        q = max(q, int(substeps))
    return q, p, float(np.max(umax))


def bilinear_step_function(model, u_min, u_max, discretisation: str = "auto", substeps: int | None = None):
    """casadi Function (z, u) -> z⁺, one sample-and-hold step of the bilinear model.

    'exact': the Taylor series of the augmented matrix exponential applied to [z; 1] (module docstring).
    'polynomial' (one input): the SAME map with its terms regrouped as a polynomial in u with constant matrix
    coefficients, Σ_d u^d (C_d z + c_d), trailing terms below rounding dropped, evaluated by Horner.  The exact
    form's expression graph nests u inside q·p matrix-vector products, so CasADi's exact Hessian of a long
    horizon grows with k²·horizon: measured on Van der Pol (k = 20), horizon 20 needs 3.5 GB and 3.4 s per IPOPT
    step, horizon 100 ≈ 17 GB.  In polynomial form ∂z⁺/∂z is a polynomial in u with constant coefficients:
    horizon 100 builds in seconds (benchmarks/lmpc.py), and the two forms agree to ~1e-15 (tests/test_oracle.py).
    'auto' (default): 'polynomial' for one input, 'exact' otherwise.  'rk4': classical RK4 with ``substeps``."""
    ca = _casadi()
    if discretisation not in DISCRETISATIONS:
        raise ConfigError(f"oracle discretisation={discretisation!r}; valid: {DISCRETISATIONS}")
    k, m = model.k, model.m
    if discretisation == "auto":
        discretisation = "polynomial" if m == 1 else "exact"
    z = ca.SX.sym("z", k)
    u = ca.SX.sym("u", m)
    lam, B, b, dt = np.asarray(model.Lambda), np.asarray(model.B), np.asarray(model.b), float(model.dt)
    if discretisation == "exact":
        q, p, _ = _step_order(model, u_min, u_max, substeps)
        zn = bilinear_step_exact(ca, lam, B, b, dt, z, u, q, p)
    elif discretisation == "polynomial":
        q, p, umax = _step_order(model, u_min, u_max, substeps)
        C = step_polynomial(lam, B, b, dt, q, p)
        keep = polynomial_terms(C, umax)
        zn = ca.mtimes(ca.DM(C[keep - 1][:k, :k]), z) + ca.DM(C[keep - 1][:k, k])
        for d in range(keep - 2, -1, -1):
            zn = u[0] * zn + ca.mtimes(ca.DM(C[d][:k, :k]), z) + ca.DM(C[d][:k, k])
    else:
        sub = 8 if substeps is None else int(substeps)
        if sub < 1:
            raise ConfigError(f"oracle substeps={substeps}: use an int >= 1")
        Bs = [ca.DM(B[i]) for i in range(m)]
        bs = [ca.DM(b[i]) for i in range(m)]
        lamd = ca.DM(lam)

        def f(zz, uu):
            out = ca.mtimes(lamd, zz)
            for i in range(m):
                out = out + uu[i] * (ca.mtimes(Bs[i], zz) + bs[i])
            return out
        zn = rk4_step(f, z, u, dt, sub)
    return ca.Function("bilinear_step", [z, u], [zn])


# ---- the shared exact objective of eq. 21 ------------------------------------------------------------------------
def lmpc_objective(model, clf, config: LmpcConfig, z0, U, active: str) -> float:
    """The LMPC objective of the block inputs U (nb, m) from z0, on kexp's exact rollout: the formula of
    ``Lmpc._exact_cost`` with the smallest feasible slack s = max(0, max_j V(z_j) − r̂) when (21e) is active
    (else s = 0).  Shared by both solvers so their optima can be compared on equal terms."""
    sizes = block_sizes(config.horizon, config.free_moves, config.blocks)
    bos = block_of_step(sizes)
    U = np.ascontiguousarray(np.asarray(U, float).reshape(len(sizes), model.m))
    Z = rollout(np.ascontiguousarray(model.Lambda), np.ascontiguousarray(model.B), np.ascontiguousarray(model.b),
                model.dt, np.ascontiguousarray(z0, dtype=float), U, bos)
    s = 0.0
    if active == "21e":
        s = max(0.0, float(np.max(clf.lyap.value(Z[1:]))) - clf.r_hat)
    zz = Z[1:] if config.state_cost == "z" else Z[1:] @ np.asarray(model.C).T
    r_diag = np.repeat(sizes.astype(float), model.m) * config.r
    cost = model.dt * config.w * float(np.sum(zz * zz)) + model.dt * float(np.sum(r_diag * U.reshape(-1) ** 2))
    cost += config.terminal * float(Z[-1] @ clf.P @ Z[-1])
    return cost + config.slack_weight * (s + s * s)


# ---- IPOPT on the LMPC problem -----------------------------------------------------------------------------------
class IpoptLmpc:
    """Eq. 21 on the bilinear model, exactly as :class:`Lmpc` poses it, solved to convergence by IPOPT.

    NLP variables w = [vec(U) (nb·m, block then input), s, z_1..z_Np (Np·k)] (multiple shooting; same optimum as
    the single-shooting QP of Lmpc), parameters p = [z_0, L_BV(z_0)].  Region switching is done by the constraint
    bounds: rows V(z_j) − s ≤ r̂ (21e) and L_BV(z_0)·u_0 ≤ L_BV(z_0)·h(z_0) (21f) get an infinite upper bound when
    inactive.  After each solve ``last_plan`` (nb, m), ``last_slack`` and ``last_objective`` (IPOPT's objective on its
    own discretisation) describe the solution; :func:`lmpc_objective` re-evaluates any plan on kexp's exact rollout.

    Check of the SQP (Van der Pol, horizon 20, no blocking, Lmpc max_iter=50, tol=1e-10, tests/test_oracle.py):
    where (21e) is imposed or (21f) does not bind, |Δu_0| ≤ 3.4e-7 and the costs agree to 3e-13 relative; where
    (21f) binds the SQP does not converge (see ``Lmpc._line_search``: its merit ignores (21f)).  Per step, IPOPT
    takes ~40 ms (10-14 iterations), the converged SQP ~3 ms, the real-time iteration ~0.5 ms.
    """

    name = "ipopt_lmpc"

    def __init__(self, model, clf, law, config: LmpcConfig, u_min, u_max, *, discretisation: str = "auto",
                 substeps: int | None = None, ipopt_tol: float = 1e-10, ipopt_max_iter: int = 1000,
                 ipopt_options: dict | None = None, record_prediction: bool = False):
        ca = _casadi()
        if not isinstance(config, LmpcConfig):
            raise ConfigError(f"IpoptLmpc: config={config!r}: pass an LmpcConfig")
        self.u_min, self.u_max = check_model_parts(model, clf, law, u_min, u_max, "IpoptLmpc")
        self.model, self.clf, self.law, self.cfg = model, clf, law, config
        self.record_prediction = record_prediction
        self.m, self.k = model.m, model.k
        self.sizes = block_sizes(config.horizon, config.free_moves, config.blocks)
        self.bos = block_of_step(self.sizes)
        self.nb = len(self.sizes)
        self.nu = self.nb * self.m
        N, k, m = config.horizon, self.k, self.m
        self.lam = np.ascontiguousarray(model.Lambda)
        self.B = np.ascontiguousarray(model.B)
        self.b = np.ascontiguousarray(model.b)
        self.P = np.asarray(clf.P, float)
        self.step_fn = bilinear_step_function(model, self.u_min, self.u_max, discretisation, substeps)

        w = ca.SX.sym("w", self.nu + 1 + N * k)
        par = ca.SX.sym("p", k + m)
        z0, beta0 = par[:k], par[k:]
        U = [w[i * m:(i + 1) * m] for i in range(self.nb)]
        s = w[self.nu]
        Z = [w[self.nu + 1 + j * k: self.nu + 1 + (j + 1) * k] for j in range(N)]
        P = ca.DM(self.P)
        C = ca.DM(np.asarray(model.C)) if config.state_cost == "x" else None
        dyn, vrows = [], []
        cost = 0
        prev = z0
        for j in range(N):
            dyn.append(self.step_fn(prev, U[self.bos[j]]) - Z[j])
            out = Z[j] if C is None else ca.mtimes(C, Z[j])
            cost = cost + model.dt * config.w * ca.sumsqr(out)
            vrows.append(ca.dot(Z[j], ca.mtimes(P, Z[j])) - s)
            prev = Z[j]
        for i in range(self.nb):
            cost = cost + model.dt * config.r * float(self.sizes[i]) * ca.sumsqr(U[i])
        if config.terminal > 0:
            cost = cost + config.terminal * ca.dot(Z[-1], ca.mtimes(P, Z[-1]))
        cost = cost + config.slack_weight * (s + s * s)
        g = ca.vertcat(*dyn, *vrows, ca.dot(beta0, U[0]))
        self._solver = ca.nlpsol("ipopt_lmpc", "ipopt", {"x": w, "p": par, "f": cost, "g": g},
                                 _ipopt_options(ipopt_tol, ipopt_max_iter, ipopt_options))
        self._lbx = np.concatenate([np.tile(self.u_min, self.nb), [0.0], np.full(N * k, -np.inf)])
        self._ubx = np.concatenate([np.tile(self.u_max, self.nb), [np.inf], np.full(N * k, np.inf)])
        self._lbg = np.concatenate([np.zeros(N * k), np.full(N + 1, -np.inf)])
        self.reset()

    def reset(self) -> None:
        self._useq = np.zeros((self.cfg.horizon, self.m))   # per-step input guess
        self.last_plan = None
        self.last_slack = float("nan")
        self.last_objective = float("nan")

    def _blocks_from_steps(self, useq):
        starts = np.concatenate([[0], np.cumsum(self.sizes)[:-1]])
        return np.ascontiguousarray(useq[starts])

    def _rollout(self, z0, U):
        return rollout(self.lam, self.B, self.b, self.model.dt, np.ascontiguousarray(z0), np.ascontiguousarray(U),
                       self.bos)

    def step(self, x0: np.ndarray, z0: np.ndarray) -> ControlStep:
        """Input for the sampled state (x0 unused; the problem is posed on z0 = Ψ(x0) − Ψ(x_eq))."""
        t0 = time.perf_counter()
        cfg, N, k = self.cfg, self.cfg.horizon, self.k
        z0 = np.ascontiguousarray(z0, dtype=float)
        ctx = lyapunov_context(self.clf, self.law, cfg, z0)
        region, h0, beta0, rhs_21f, active = ctx.region, ctx.h0, ctx.beta0, ctx.rhs_21f, ctx.active
        if not np.all(np.isfinite(z0)):
            return self._fallback(h0, "non-finite state z", region, active, t0, "not_run", 0)
        Ubar = self._blocks_from_steps(self._useq)
        Zbar = self._rollout(z0, Ubar)
        w0 = np.concatenate([Ubar.reshape(-1), [0.0], Zbar[1:].reshape(-1)])
        ubg = np.concatenate([np.zeros(N * k), np.full(N, self.clf.r_hat if active == "21e" else np.inf),
                              [rhs_21f if active == "21f" else np.inf]])
        sol, status, iters, why = _solve(self._solver, dict(x0=w0, p=np.concatenate([z0, beta0]), lbx=self._lbx,
                                                            ubx=self._ubx, lbg=self._lbg, ubg=ubg))
        if sol is None:
            return self._fallback(h0, why, region, active, t0, status, iters)
        wopt = np.asarray(sol["x"], float).reshape(-1)
        U = np.clip(wopt[: self.nu].reshape(self.nb, self.m), self.u_min, self.u_max)
        self.last_plan = U.copy()
        self.last_slack = float(wopt[self.nu])
        self.last_objective = float(sol["f"])
        u0 = U[0].copy()
        slack, binds, Z = 0.0, False, None
        if active == "21e" or self.record_prediction:   # the exact (kexp) prediction of the applied plan
            Z = self._rollout(z0, U)
        if active == "21e":
            vmax = float(np.max(self.clf.lyap.value(Z[1:])))
            slack = max(0.0, vmax - self.clf.r_hat)
            binds = vmax >= self.clf.r_hat - 1e-6 * max(1.0, self.clf.r_hat)
        elif active == "21f":
            binds = abs(float(beta0 @ u0) - rhs_21f) <= 1e-6 * max(1.0, abs(rhs_21f))
        useq = U[self.bos]
        self._useq = np.vstack([useq[1:], useq[-1:]])
        return ControlStep(u=u0, status="solved", qp_status=status, iterations=iters, qp_iterations=iters,
                           solve_time=time.perf_counter() - t0, region=region, active=active, binds=bool(binds),
                           slack=slack, fallback=False, reason="", predicted=Z)

    def _fallback(self, h0, why, region, active, t0, status, iters) -> ControlStep:
        self.reset()
        return ControlStep(u=np.clip(h0, self.u_min, self.u_max), status="fallback", qp_status=status,
                           iterations=iters, qp_iterations=iters, solve_time=time.perf_counter() - t0,
                           region=region, active=active, binds=False, slack=0.0, fallback=True,
                           reason=f"IPOPT failed ({why}); applied h(z)")
