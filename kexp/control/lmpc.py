"""Lyapunov-based MPC (paper eq. 21) on the bilinear Koopman model, by SQP on a dense QP solver.

Decision variables: the move-blocked input sequence U (nb, m) and one slack s ≥ 0.
    min  Δ Σ_{j=1..Np} ℓ(z_j) + Δ Σ_j u_jᵀ R u_j + w_T·V(z_Np) + ρ(s + s²)
    s.t. z_{j+1} = exact sample-and-hold step of ż = Λz + Σu_i(B_i z + b_i)      (21b, 21c)
         u_min ≤ u ≤ u_max                                                     (21d)
         V(z_j) ≤ r̂ + s, j = 1..Np        if V(z_0) ≤ r̂   (inside Ω_r̂)          (21e, softened)
         L_BV(z_0)·u_0 ≤ L_BV(z_0)·h(z_0)  if V(z_0) > r̂   (ring and outside)     (21f)
with ℓ(z) = w‖z‖² (state_cost 'z', W = wI) or w‖Cz‖² (state_cost 'x', a cost on x through C).
(21f) is linear in u_0 and exact; u = h(z_0) satisfies it, so the QP is feasible whenever h is within bounds.
Outside Ω_r the paper gives no constraint; kexp keeps (21f) there too.

Each SQP iteration linearises the exact rollout around the current guess (warm start: the previous solution
shifted by one step), condenses it into a dense QP in (U, s) and solves it (kexp.control.ipm, DAQP or PIQP).
``max_iter = 1`` is the real-time iteration (one QP per step).  A failed QP falls back to h(z_0) and says why.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError, require_number
from .blocking import block_of_step, block_sizes
from .checks import check_lmpc_config, check_model_parts
from .condense import balancing, block_maps_expm, block_maps_poly, condense, linearised_vmax, rows_hold
from .kernels import rollout, rollout_poly
from .memory import check_memory
from .qp import SOLVERS, DenseQp
from .zoh_poly import zoh_polynomial

STATE_COSTS = ("z", "x")
ITERATE_WHEN = ("always", "binding")


@dataclass(frozen=True)
class LmpcConfig:
    """Settings of :class:`Lmpc` (frozen; checked on construction, :class:`~kexp.errors.ConfigError` naming the
    ``lmpc.<key>`` otherwise): ``horizon`` Np steps of the model's Δ; weights ``w`` > 0 on the state (on z, or on
    x = Cz with ``state_cost='x'``) and ``r`` > 0 on u; ``terminal`` w_T ≥ 0 on V(z_Np); move blocking with
    ``free_moves`` single-step moves then ``blocks`` blocks in all (``blocks=None``: no blocking); ``max_iter``
    SQP iterations per step (1: real-time iteration) stopping at step size ``tol``; ``iterate_when`` 'always'
    (up to ``max_iter`` in every step) or 'binding' (past the first QP only when its solution has an input bound or
    a Lyapunov constraint active: the real-time iteration elsewhere); ``slack_weight`` ρ of the
    softened (21e); ``use_21e`` / ``use_21f`` switch those constraints; ``qp_solver`` 'daqp' (default: dual active
    set, warm-started, exact at the bounds), 'ipm' (kexp's compiled interior point, :mod:`kexp.control.ipm`) or 'piqp', with its
    tolerance ``qp_eps`` and iteration limit ``qp_max_iter``."""

    horizon: int = 100
    w: float = 1.0
    r: float = 1.0
    state_cost: str = "z"
    terminal: float = 0.0
    free_moves: int | None = 5
    blocks: int | None = 20
    max_iter: int = 1
    tol: float = 1e-6
    iterate_when: str = "always"
    slack_weight: float = 1e4
    use_21e: bool = True
    use_21f: bool = True
    qp_solver: str = "daqp"
    qp_eps: float = 1e-8
    qp_max_iter: int = 100

    def __post_init__(self):
        check_lmpc_config(self, STATE_COSTS, ITERATE_WHEN, SOLVERS)


@dataclass(frozen=True)
class ControlStep:
    """What a controller did at one sampling instant."""

    u: np.ndarray
    status: str              # 'solved', 'fallback', 'explicit'
    qp_status: str
    iterations: int          # SQP iterations
    qp_iterations: int
    solve_time: float        # wall-clock seconds for the whole step
    region: str              # 'inner' (Ω_r̂), 'ring' (Ω_r∖Ω_r̂), 'outside'
    active: str              # '21e', '21f', 'none'
    binds: bool
    slack: float
    fallback: bool
    reason: str
    predicted: np.ndarray | None = None   # predicted z over the horizon (Np+1, k)


def region_of(V0: float, r: float, r_hat: float) -> str:
    return "inner" if V0 <= r_hat else ("ring" if V0 <= r else "outside")


@dataclass(frozen=True)
class LyapunovContext:
    """What eq. 21 needs to know about z(t_k): V, the region, h(z), L_BV(z), the (21f) bound and the active
    Lyapunov constraint.  Shared by every solver of the LMPC problem."""

    V0: float
    region: str
    h0: np.ndarray
    beta0: np.ndarray
    rhs_21f: float
    active: str


def lyapunov_context(clf, law, config: LmpcConfig, z0: np.ndarray) -> LyapunovContext:
    """V, L_ΛV and L_BV at z0 once (:meth:`QuadraticLyapunov.at`), h(z0) from them when the law has ``single``
    (kexp's laws), else by calling it on the batch z0[None] (any callable z (..., k) -> u (..., m))."""
    V0, a0, beta0 = clf.lyap.at(z0)
    region = region_of(V0, clf.r, clf.r_hat)
    single = getattr(law, "single", None)
    h0 = single(z0, a0, beta0) if single is not None else law(z0[None])[0]
    if region == "inner":
        active = "21e" if config.use_21e else "none"
    else:
        active = "21f" if config.use_21f else "none"
    return LyapunovContext(V0, region, h0, beta0, float(beta0 @ h0), active)


class Lmpc:
    """Stateful controller: call :meth:`step` with z(t_k) each sampling instant; :meth:`reset` between runs."""

    name = "lmpc"

    def __init__(self, model, clf, law, config: LmpcConfig, u_min, u_max, *, prediction_every: int = 0):
        """``prediction_every``: return the exact predicted z over the horizon every this many steps (0:
        never); it costs one extra rollout.  Raises :class:`~kexp.errors.ConfigError` for bounds that are not finite
        u_min < u_max, a CLF or law that does not fit the model (:mod:`kexp.control.checks`; a law on other bounds
        only warns), a bad ``prediction_every`` or a horizon over the memory budget."""
        if not isinstance(config, LmpcConfig):
            raise ConfigError(f"Lmpc: config={config!r}: pass an LmpcConfig")
        require_number(prediction_every, "Lmpc prediction_every", integer=True)
        if prediction_every < 0:
            raise ConfigError(f"Lmpc prediction_every={prediction_every}: use an int >= 0 (0: never)")
        self.u_min, self.u_max = check_model_parts(model, clf, law, u_min, u_max, "Lmpc")
        self.model, self.clf, self.law, self.cfg = model, clf, law, config
        self.prediction_every = int(prediction_every)
        self.m, self.k = model.m, model.k
        check_memory(config, self.k, self.m)
        self.sizes = block_sizes(config.horizon, config.free_moves, config.blocks)
        self.bos = block_of_step(self.sizes)
        self.nb = len(self.sizes)
        self.nu = self.nb * self.m
        # two QPs of fixed structure: Np rows of (21e) inside Ω_r̂, one row ((21f), or an inactive 0 ≤ 1) elsewhere;
        # the QP's work per iteration grows with the rows, and most steps need only one
        qp = dict(eps=config.qp_eps, max_iter=config.qp_max_iter, solver=config.qp_solver)
        self.qp_e = DenseQp(self.nu + 1, config.horizon, **qp)
        self.qp_f = DenseQp(self.nu + 1, 1, **qp)
        # owned, writable, C-ordered copies: a read-only array (a model or P from kexp's cache, a user's
        # frozen array) is another type to numba, whose kernels would compile again for it (kexp.control.jit_cache)
        self.lam, self.B, self.b, self.P = (np.array(a, order="C")
                                            for a in (model.Lambda, model.B, model.b, clf.P))
        self.out = np.array(model.C, order="C") if config.state_cost == "x" else None
        self.r_diag = np.repeat(self.sizes.astype(float), self.m) * config.r
        self.x_l = np.concatenate([np.tile(self.u_min, self.nb), [0.0]])
        self.x_u = np.concatenate([np.tile(self.u_max, self.nb), [np.inf]])
        # one input: the exact ZOH map as a polynomial in u on the input range (kexp.control.zoh_poly), so the map
        # and its derivative cost a few matrix additions per move block; else (or out of range) the exponential
        rho = float(max(np.max(np.abs(self.u_min)), np.max(np.abs(self.u_max))))
        self.zoh = zoh_polynomial(self.lam, self.B, self.b, model.dt, rho)
        # else the exponential, of the balanced generators where that saves a halving (kexp.control.condense)
        self._bal = balancing(self.lam, self.B, self.b, model.dt, rho) if self.zoh is None else None
        self._buffers()
        self.reset()
        # compile (or load from numba's cache) now, not inside the first control step: the condensing, and the
        # rollout of a logged plan or a line search
        self._maps(np.zeros((self.nb, self.m)))
        self._condense(np.zeros(self.k), np.zeros(self.nu), True)
        self._rollout(np.zeros(self.k), np.zeros((self.nb, self.m)))
        rows_hold(self._rows, self._h_rows, np.zeros(self.nu + 1), 1.0)
        linearised_vmax(self._Z, self._S, np.zeros(self.nu), self.P, self._first, self._zz[: self.k], self._PS[0])

    def _buffers(self) -> None:
        """The arrays the compiled condensing writes into, allocated once (kexp.control.condense)."""
        k, n, nu, Np, m = self.k, self.k + 1, self.nu, self.cfg.horizon, self.m
        starts = np.concatenate([[0], np.cumsum(self.sizes)[:-1]]).astype(np.int64)
        self._starts = starts
        self._first = np.repeat(starts, m)                 # the step at which each column's block starts
        self._shift = np.append(self.bos[1:], self.bos[-1])  # the plan one step on: the next step's warm start
        self._E = np.zeros((self.nb, n, n))
        self._L = np.zeros((self.nb, m, n, n))
        self._Z = np.zeros((Np + 1, k))
        self._S = np.zeros((nu, Np + 1, k))                # zero before each column's block: never written
        self._C = self.out if self.out is not None else np.zeros((1, k))
        self._Y = np.zeros((nu + 1, Np + 1, self._C.shape[0]) if self.out is not None else (1, 1, 1))
        self._HS = np.zeros((nu, nu))
        self._q = np.zeros(nu)
        self._rows = np.zeros((Np, nu))
        self._Vbar = np.zeros(Np)
        self._h_rows = np.zeros(Np)
        self._zz = np.zeros(n)
        self._PS = np.zeros((nu, k))
        self._rdiag = 2 * self.model.dt * self.r_diag + 1e-10
        self._scale = 2 * self.model.dt * self.cfg.w
        # the QP's arrays: H is symmetric, so its C-ordered buffer is also the column-major one PIQP reads (H.T),
        # and the row-major one kexp's interior point reads
        self._H = np.zeros((nu + 1, nu + 1))
        self._H[-1, -1] = 2 * self.cfg.slack_weight
        self._g = np.zeros(nu + 1)
        self._g[-1] = self.cfg.slack_weight
        self._G_rows = np.zeros((Np, nu + 1), order="F")   # all Np (21e) rows, filled when the full QP is solved
        self._G_rows[:, -1] = -1.0
        self._G_one = np.zeros((1, nu + 1), order="F")     # the one row: (21f), the most binding (21e), or 0 ≤ 1
        self._h_one = np.ones(1)

    def reset(self) -> None:
        self._useq = np.zeros((self.cfg.horizon, self.m))  # per-step guess
        self._count = 0

    def _blocks_from_steps(self, useq: np.ndarray) -> np.ndarray:
        return useq[self._starts]                 # fancy indexing: a new C-contiguous (nb, m) array

    # -- cost and constraints -------------------------------------------------------------------------------
    def _exact_cost(self, Z, U, s) -> float:
        cfg, dt = self.cfg, self.model.dt
        zz = Z[1:] if self.out is None else Z[1:] @ self.out.T
        cost = dt * cfg.w * float(np.sum(zz * zz)) + dt * float(np.sum(self.r_diag * (U.reshape(-1) ** 2)))
        cost += cfg.terminal * float(Z[-1] @ self.P @ Z[-1])
        return cost + cfg.slack_weight * (s + s * s)

    def _maps(self, Ubar) -> None:
        """E_b and L_b = ∂E_b/∂u of every move block at the guess Ubar (nb, m), into the buffers."""
        if self.zoh is not None:
            block_maps_poly(self.zoh.coef, self.zoh.norms, self.zoh.rho, self.lam, self.B, self.b, self.model.dt,
                            Ubar, self._E, self._L)
        elif self._bal is None:
            block_maps_expm(self.lam, self.B, self.b, self.model.dt, Ubar, self._E, self._L)
        else:                                   # expm(S⁻¹MS) = S⁻¹expm(M)S, S = diag(powers of two): exact
            lam_b, B_b, b_b, ratio = self._bal
            block_maps_expm(lam_b, B_b, b_b, self.model.dt, Ubar, self._E, self._L)
            self._E *= ratio
            self._L *= ratio

    def _condense(self, z0, ub, want_rows: bool) -> None:
        """The rollout, sensitivities, H, g and (with ``want_rows``) the (21e) rows at the guess ub = vec(U), from the
        block maps of :meth:`_maps`, into the buffers (:func:`kexp.control.condense.condense`)."""
        condense(self._E, self._L, self.bos, self._first, z0, ub, self._C, self.out is not None, self._scale,
                 self._rdiag, self.P, float(self.cfg.terminal), self.clf.r_hat, want_rows, self._Z, self._S, self._Y,
                 self._HS, self._q, self._H, self._g, self._rows, self._Vbar, self._h_rows, self._zz, self._PS)

    def _rollout(self, z0, U):
        """The exact prediction Z (Np+1, k) of the plan U: from the ZOH polynomial where there is one."""
        if self.zoh is not None:
            zp = self.zoh
            return rollout_poly(zp.coef, zp.norms, zp.rho, self.lam, self.B, self.b, self.model.dt, z0, U, self.bos)
        return rollout(self.lam, self.B, self.b, self.model.dt, z0, U, self.bos)

    def _qp_data(self, z0, Ubar, active, rhs_21f, beta0):
        """The condensed QP at the guess Ubar, z_j ≈ z̄_j + S_j·vec(U − Ubar) (cost and terminal cost from the
        compiled pass, :meth:`_condense`): (H, g, G, h_u) with one constraint row.  Inside Ω_r̂ that row is the
        (21e) row with the least margin at the guess (:meth:`_solve` checks the solution against all Np rows and
        solves with all of them if one is violated); else (21f), or 0 ≤ 1."""
        ub = Ubar.reshape(-1)
        self._ub = ub
        self._maps(Ubar)
        self._condense(z0, ub, active == "21e")
        H, g = self._H, self._g
        G, h_u = self._G_one, self._h_one
        if active == "21e":                          # V(z_j) ≤ r̂ + s, linearised
            j = int(np.argmax(self._Vbar))
            G[0, : self.nu] = self._rows[j]
            G[0, -1] = -1.0
            h_u[0] = self._h_rows[j]
        else:                                        # (21f) on u_0 (the first block's input), or inactive (0 ≤ 1)
            G[0, :] = 0.0
            h_u[0] = 1.0
            if active == "21f":
                G[0, : self.m] = beta0
                h_u[0] = rhs_21f
        return H, g, G, h_u

    def _rows_violation(self, x) -> np.ndarray:
        """rows·U − s − h of all Np linearised (21e) rows at the QP variables x = (vec U, s)."""
        return self._rows @ x[: self.nu] - x[-1] - self._h_rows

    def _solve(self, H, g, G, h_u, active):
        """The QP with the one row of :meth:`_qp_data`; inside Ω_r̂, if its solution violates another (21e) row (by
        more than the QP's tolerance), the QP with all Np rows.  The same solution: the one-row QP's feasible set
        contains the full one's, so a solution of it that satisfies every row is the full QP's (strictly convex).
        Returns the result and the QP iterations of both solves."""
        res = self.qp_f.solve(H.T, g, G, h_u, self.x_l, self.x_u)    # H is symmetric: H.T is its column-major view
        if not (res.success and active == "21e"):
            return res, res.iterations
        if rows_hold(self._rows, self._h_rows, res.x, self.cfg.qp_eps):
            return res, res.iterations
        self._G_rows[:, : self.nu] = self._rows
        full = self.qp_e.solve(H.T, g, self._G_rows, self._h_rows, self.x_l, self.x_u)
        return full, res.iterations + full.iterations

    # -- one sampling instant ---------------------------------------------------------------------------------
    def step(self, x0: np.ndarray, z0: np.ndarray) -> ControlStep:
        """Input for the sampled state: x0 (n,) is unused (the LMPC works on z0 = Ψ(x0) − Ψ(x_eq), (k,))."""
        t0 = time.perf_counter()
        cfg = self.cfg
        z0 = np.ascontiguousarray(z0, dtype=float)
        ctx = lyapunov_context(self.clf, self.law, cfg, z0)
        region, h0, beta0, rhs_21f, active = ctx.region, ctx.h0, ctx.beta0, ctx.rhs_21f, ctx.active
        if not np.isfinite(z0).all():
            return self._fallback(h0, "non-finite state z", region, active, t0, "not_run", 0, 0)
        Ubar = self._blocks_from_steps(self._useq)
        qp_iters = 0
        res = None
        it = 0
        for it in range(1, cfg.max_iter + 1):
            H, g, G, h_u = self._qp_data(z0, Ubar, active, rhs_21f, beta0)
            res, iters = self._solve(H, g, G, h_u, active)
            qp_iters += iters
            if not res.success:
                return self._fallback(h0, res.message or res.status, region, active, t0, res.status, it, qp_iters)
            # np.minimum(np.maximum(·)) is np.clip's result (NaN included) at half its call cost on small arrays
            Unew = np.minimum(np.maximum(res.x[: self.nu].reshape(self.nb, self.m), self.u_min), self.u_max)
            if cfg.max_iter > 1:
                Unew = self._line_search(z0, Ubar, Unew - Ubar, active, beta0, rhs_21f)
            done = cfg.max_iter == 1 or np.max(np.abs(Unew - Ubar)) <= cfg.tol
            if it == 1 and cfg.iterate_when == "binding" and not self._qp_binds(res.x, Unew, active, beta0, rhs_21f):
                done = True   # nothing active: the real-time iteration's answer is the step's
            Ubar = np.ascontiguousarray(Unew)
            if done:
                break
        u0 = Ubar[0].copy()
        slack, binds = 0.0, False
        Z = None
        want = self.prediction_every > 0 and self._count % self.prediction_every == 0
        self._count += 1
        if want:  # the exact prediction of the applied plan, for the log
            Z = self._rollout(z0, Ubar)
        if active == "21e":
            # slack and binding as the QP saw them: the linearised prediction at the applied plan (an exact rollout
            # here cost 0.48 ms, a quarter of the step; the plan's exact prediction is logged when requested)
            vmax = linearised_vmax(self._Z, self._S, Ubar.reshape(-1) - self._ub, self.P, self._first,
                                   self._zz[: self.k], self._PS[0])
            slack = max(0.0, vmax - self.clf.r_hat)
            binds = vmax >= self.clf.r_hat - 1e-6 * max(1.0, self.clf.r_hat)
        elif active == "21f":
            lhs = float(beta0 @ u0)
            binds = abs(lhs - rhs_21f) <= 1e-6 * max(1.0, abs(rhs_21f))
        # warm start: shift the per-step sequence by one step
        self._useq = Ubar[self._shift]
        return ControlStep(u=u0, status="solved", qp_status=res.status, iterations=it, qp_iterations=qp_iters,
                           solve_time=time.perf_counter() - t0, region=region, active=active, binds=bool(binds),
                           slack=slack, fallback=False, reason="", predicted=Z)

    def _qp_binds(self, xsol, U, active, beta0, rhs_21f) -> bool:
        """Whether the QP's solution has an input bound or a (linearised) Lyapunov constraint active.  An
        interior point stops short of an active bound (measured up to ~2e-4 inside for PIQP and ~2e-6 for kexp's
        at eps 1e-8, benchmarks/qp.py), hence the margins: an
        input within 0.1 % of its range from a bound, a row within 1e-4 (relative) of its right-hand side.  DAQP's
        solution lies on the bounds it holds active (its active set is exact), so there an input counts within
        1e-12 of its range and a row within 1e-9 (relative: rounding of the rows' products, ~1e-15, with room).  On
        the benchmark problem (max_iter 5, 3 x0 × 5 s) both rules iterate in the same 58 % of the steps."""
        span = self.u_max - self.u_min
        exact = self.cfg.qp_solver == "daqp"
        u_margin, row_margin = (1e-12, 1e-9) if exact else (1e-3, 1e-4)
        if np.any(U <= self.u_min + u_margin * span) or np.any(U >= self.u_max - u_margin * span):
            return True
        if active == "21e":
            return bool(np.any(self._rows_violation(xsol) >= -row_margin * np.maximum(1.0, np.abs(self._h_rows))))
        if active == "21f":
            return float(beta0 @ xsol[: self.m]) - rhs_21f >= -row_margin * max(1.0, abs(rhs_21f))
        return False

    def _line_search(self, z0, Ubar, step, active, beta0, rhs_21f):
        """Backtracking on the exact merit: cost + slack penalty of (21e) + ρ·violation of (21f) (the warm start
        may violate (21f), e.g. after a reset; without the last term no step towards feasibility is accepted)."""
        def merit(U):
            Z = self._rollout(z0, np.ascontiguousarray(U))
            s = 0.0
            if active == "21e":
                s = max(0.0, float(np.max(self.clf.lyap.value(Z[1:]))) - self.clf.r_hat)
            viol = max(0.0, float(beta0 @ U[0]) - rhs_21f) if active == "21f" else 0.0
            return self._exact_cost(Z, U, s) + self.cfg.slack_weight * viol
        base = merit(Ubar)
        alpha = 1.0
        for _ in range(8):
            cand = np.clip(Ubar + alpha * step, self.u_min, self.u_max)
            if merit(cand) <= base:
                return cand
            alpha *= 0.5
        return np.clip(Ubar + alpha * step, self.u_min, self.u_max)

    def _fallback(self, h0, why, region, active, t0, qp_status, it, qp_iters) -> ControlStep:
        self.reset()
        return ControlStep(u=np.clip(h0, self.u_min, self.u_max), status="fallback", qp_status=qp_status,
                           iterations=it, qp_iterations=qp_iters, solve_time=time.perf_counter() - t0,
                           region=region, active=active, binds=False, slack=0.0, fallback=True,
                           reason=f"QP failed ({why}); applied h(z)")
