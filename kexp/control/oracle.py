"""The true-model oracle: :class:`NmpcOracle`, a nonlinear MPC on the TRUE system solved to convergence by CasADi +
IPOPT, with the step interface of :class:`~kexp.control.lmpc.Lmpc` (``name``, ``reset()``,
``step(x0, z0) -> ControlStep``) — a yardstick for what any model-based controller could achieve.  It needs the
system's drift symbolically: :func:`register_symbolic` keeps one per system class (the library's are registered on
import) and :func:`symbolic_dynamics` builds the casadi right-hand side from it, checked against the system's own
drift/input_matrix.  The true dynamics are discretised by sample-and-hold RK4 (``substeps`` per Δ).

The CasADi import, the input bounds, the IPOPT options and the solve are shared with the LMPC's NLP,
:mod:`kexp.control.bilinear_nlp` (whose docstring describes them): ``print_level 0``, exact Hessian,
``bound_relax_factor 0``; the NLP is built once and warm-started from the previous solution shifted by one step; a
solve that does not end in 'Solve_Succeeded' or 'Solved_To_Acceptable_Level' (or raises, or returns non-finite
numbers) falls back (here to ``law(z0)`` if a law is given, else to the saturated LQR feedback) and says why;
:meth:`NmpcOracle.step` never raises on a solver failure.  The ``ControlStep`` fields are filled as there.

casadi is optional (``pip install casadi``, the extra ``kexp[oracle]``), imported on first use.
"""
from __future__ import annotations

import time
from typing import Callable

import numpy as np
import scipy.linalg as sla

from ..errors import ConfigError
from .bilinear_nlp import _casadi, _ipopt_options, _solve, rk4_step
from .checks import input_bounds
from .blocking import block_of_step, block_sizes
from .explicit import linearise
from .lmpc import ControlStep, region_of

# ---- symbolic true dynamics --------------------------------------------------------------------------------------
_SYMBOLIC: dict[type, Callable] = {}


def register_symbolic(cls: type, fn: Callable) -> None:
    """Register the symbolic dynamics of a system class: ``fn(system, x) -> (F, G)`` with x a casadi SX column
    (n×1), F (n×1) and G (n×m) casadi expressions (or numbers/arrays).  Matching is by exact class (a subclass
    that changes the dynamics needs its own entry)."""
    if not isinstance(cls, type) or not callable(fn):
        raise ConfigError(f"register_symbolic: need a class and a callable, got {cls!r}, {fn!r}")
    _SYMBOLIC[cls] = fn


def _register_builtin() -> None:
    from ..systems.library import CartPendulum, Duffing, Linear, Pendulum, SlowManifold, VanDerPol

    def vdp(s, x):
        ca = _casadi()
        return ca.vertcat(x[1], s.mu * (1 - x[0] ** 2) * x[1] - x[0]), np.array([[0.0], [1.0]])

    def pendulum(s, x):
        ca = _casadi()
        return ca.vertcat(x[1], s.c * x[1] - ca.sin(x[0])), np.array([[0.0], [1.0]])

    def duffing(s, x):
        ca = _casadi()
        return (ca.vertcat(x[1], -s.delta * x[1] + s.alpha * x[0] - s.beta * x[0] ** 3), np.array([[0.0], [1.0]]))

    def linear(s, x):
        ca = _casadi()
        return ca.mtimes(ca.DM(np.asarray(s.A, float)), x), np.asarray(s.B, float)

    def slow(s, x):
        ca = _casadi()
        G = {"x2": np.array([[0.0], [1.0]]), "both": np.eye(2), "x2_varying": ca.vertcat(0, 1 + x[0])}[s.inputs]
        return ca.vertcat(s.mu * x[0], s.lam * (x[1] - x[0] ** 2)), G

    def cart_pendulum(s, x):
        ca = _casadi()
        return (ca.vertcat(x[1], s.g_over_l * ca.sin(x[0]) - s.damping * x[1]),
                ca.vertcat(0, -ca.cos(x[0]) / s.length))

    for cls, fn in ((VanDerPol, vdp), (Pendulum, pendulum), (Duffing, duffing), (Linear, linear),
                    (SlowManifold, slow), (CartPendulum, cart_pendulum)):
        register_symbolic(cls, fn)


_register_builtin()


def symbolic_model(system):
    """``(x, F, G, source)``: SX expressions of ``system``'s F (n×1) and G (n×m) at the SX symbol x (n×1), from the
    registry (``source`` 'registered') or traced from the system's own numpy code (:mod:`kexp.control.trace`,
    ``source`` 'traced'); raises :class:`~kexp.errors.ConfigError` with the trace's reason and the fix when
    neither works."""
    ca = _casadi()
    n, m = system.n, system.m
    fn = _SYMBOLIC.get(type(system))
    if fn is not None:
        x = ca.SX.sym("x", n)
        F, G = fn(system, x)
        return x, ca.SX(F), ca.SX(G), "registered"
    from .trace import TraceError, trace_system
    try:
        x, F, G = trace_system(system)
    except TraceError as exc:
        raise ConfigError(f"oracle: system {type(system).__name__} has no symbolic model and its numpy code could "
                          f"not be traced ({exc}); write drift/input_matrix without float conversions or branches "
                          f"on x, or register one with register_symbolic({type(system).__name__}, fn) where "
                          f"fn(system, x) -> (F, G)") from None
    return x, F, G, "traced"


def symbolic_dynamics(system, *, check: bool = True, with_source: bool = False):
    """casadi Function (x, u) -> ẋ = F(x) + G(x)u of ``system`` (:func:`symbolic_model`: registered or traced);
    with ``check`` it is compared with ``system.drift``/``input_matrix`` at a few states around the equilibrium.
    ``with_source`` returns ``(function, source)``."""
    ca = _casadi()
    x, F, G, source = symbolic_model(system)
    n, m = system.n, system.m
    u = ca.SX.sym("u", m)
    if F.shape != (n, 1) or G.shape != (n, m):
        raise ConfigError(f"nmpc oracle: symbolic model of {type(system).__name__} gives F {F.shape}, G {G.shape}; "
                          f"need ({n}, 1) and ({n}, {m})")
    f = ca.Function("true_rhs", [x, u], [F + ca.mtimes(G, u)])
    if check:
        probe = np.asarray(system.equilibrium, float) + np.random.default_rng(0).uniform(-1, 1, (4, n))
        up = np.random.default_rng(1).uniform(-1, 1, (4, m))
        want = system.rhs(probe, up)
        got = np.array([np.asarray(f(xp, uu), float).reshape(-1) for xp, uu in zip(probe, up)])
        if not np.allclose(got, want, rtol=1e-9, atol=1e-9):
            raise ConfigError(f"nmpc oracle: the {source} symbolic model of {type(system).__name__} disagrees with "
                              f"its drift/input_matrix (max error {np.max(np.abs(got - want)):.3g}); fix the "
                              f"registered fn (or register one if the trace is wrong)")
    return (f, source) if with_source else f


# ---- NMPC on the true system -------------------------------------------------------------------------------------
INITS = ("zero", "lqr")      # the oracles' first guess after a reset


class TrueModelOracle:
    """What the true-model oracles share: the validated horizon, weights and bounds, the move blocking from
    ``config``, the LQR gain and terminal matrix of the true linearisation, ``reset`` and the fallback step.
    Subclasses set ``solver_label`` (named in a fallback's reason) and implement ``step``."""

    name = "nmpc_oracle"
    solver_label = "the solver"

    def _setup(self, system, config, u_min, u_max, horizon_steps, dt, q, r, terminal, substeps, clf, law,
               record_prediction, init="lqr"):
        if init not in INITS:
            raise ConfigError(f"nmpc init={init!r}; valid: {INITS} (the first guess after a reset: zero inputs, or "
                              "the saturated LQR feedback rolled out on the true system)")
        self.init = init
        if not (isinstance(horizon_steps, (int, np.integer)) and horizon_steps >= 1):
            raise ConfigError(f"nmpc horizon_steps={horizon_steps}: use an int >= 1")
        if not (dt > 0 and q > 0 and r > 0 and isinstance(substeps, (int, np.integer)) and substeps >= 1):
            raise ConfigError(f"nmpc dt={dt}, q={q}, r={r}, substeps={substeps}: need all > 0 (substeps an int >= 1)")
        self.system, self.cfg, self.clf, self.law = system, config, clf, law
        self.record_prediction = record_prediction
        self.n, self.m = system.n, system.m
        self.N, self.dt, self.q, self.r, self.substeps = int(horizon_steps), float(dt), float(q), float(r), int(substeps)
        self.u_min, self.u_max = input_bounds(u_min, u_max, self.m)
        self.x_eq = np.asarray(system.equilibrium, float)
        free = getattr(config, "free_moves", None) if config is not None else None
        blocks = getattr(config, "blocks", None) if config is not None else None
        self.sizes = block_sizes(self.N, free, blocks)
        self.bos = block_of_step(self.sizes)
        self.nb = len(self.sizes)
        self.nu = self.nb * self.m
        A, Bl = linearise(system)
        Xric = sla.solve_continuous_are(A, Bl, q * np.eye(self.n), r * np.eye(self.m))
        self.K = np.linalg.solve(r * np.eye(self.m), Bl.T @ Xric)   # fallback LQR gain
        if terminal is None or (isinstance(terminal, str) and terminal == "none"):
            Xt = np.zeros((self.n, self.n))
        elif isinstance(terminal, str):
            if terminal != "lqr":
                raise ConfigError(f"nmpc terminal={terminal!r}; valid: 'lqr', 'none'/None or an (n, n) matrix")
            Xt = Xric
        else:
            Xt = np.asarray(terminal, float)
            if Xt.shape != (self.n, self.n) or not np.all(np.isfinite(Xt)):
                raise ConfigError(f"nmpc terminal matrix has shape {Xt.shape}; need a finite ({self.n}, {self.n})")
        self.terminal_matrix = Xt

    def reset(self) -> None:
        self._useq = np.zeros((self.N, self.m))
        self._cold = True
        self.last_plan = None
        self.last_objective = float("nan")

    def _one_step(self, x, u) -> np.ndarray:
        """x after one Δ with u held, by the oracle's own RK4 map."""
        raise NotImplementedError

    def _lqr_guess(self, x0) -> np.ndarray:
        """Per-step inputs (N, m) of the saturated LQR feedback rolled out from x0 on the true RK4 map (a first guess
        in the stabilising family of plans: from zero inputs a long horizon lets an unstable system fall first, and
        a local solver may stay with plans that swing through)."""
        useq = np.zeros((self.N, self.m))
        x = np.asarray(x0, float)
        for j in range(self.N):
            u = np.clip(-self.K @ (x - self.x_eq), self.u_min, self.u_max)
            useq[j] = u
            x = self._one_step(x, u)
            if not np.all(np.isfinite(x)):
                break
        return useq

    def _first_guess(self, x0) -> np.ndarray:
        """The block inputs to start from: the previous plan shifted by one step, or after a reset ``init``'s."""
        if self._cold and self.init == "lqr":
            self._useq = self._lqr_guess(x0)
        self._cold = False
        return self._warm_blocks()

    def _region(self, z0) -> str:
        if self.clf is not None and z0 is not None and np.size(z0) > 0:
            return region_of(float(self.clf.lyap.value(np.asarray(z0, float))), self.clf.r, self.clf.r_hat)
        return "n/a"

    def _warm_blocks(self) -> np.ndarray:
        """The previous plan shifted by one step, as block inputs (the first step of each block)."""
        starts = np.concatenate([[0], np.cumsum(self.sizes)[:-1]])
        return self._useq[starts]

    def _keep_plan(self, U: np.ndarray, objective: float) -> None:
        self.last_plan = U.copy()
        self.last_objective = float(objective)
        useq = U[self.bos]
        self._useq = np.vstack([useq[1:], useq[-1:]])

    def _fallback(self, x0, z0, why, region, t0, status, iters) -> ControlStep:
        self.reset()
        if self.law is not None and z0 is not None and np.size(z0) > 0 and np.all(np.isfinite(z0)):
            u, what = np.asarray(self.law(np.asarray(z0, float)[None])[0], float), "h(z)"
        else:
            e = np.where(np.isfinite(x0), x0 - self.x_eq, 0.0)
            u, what = -self.K @ e, "the LQR feedback"
        return ControlStep(u=np.clip(u, self.u_min, self.u_max), status="fallback", qp_status=status,
                           iterations=iters, qp_iterations=iters, solve_time=time.perf_counter() - t0,
                           region=region, active="none", binds=False, slack=0.0, fallback=True,
                           reason=f"{self.solver_label} failed ({why}); applied {what}")


class NmpcOracle(TrueModelOracle):
    """Nonlinear MPC on the TRUE system, solved by IPOPT (multiple shooting, sample-and-hold RK4 with
    ``substeps`` on F(x) + G(x)u):

        min  Δ Σ_{j=1..N} q‖x_j − x_eq‖² + Δ Σ_{j=0..N−1} r‖u_j‖² + (x_N − x_eq)ᵀ X (x_N − x_eq),   u_min ≤ u ≤ u_max,

    X = 0 (``terminal=None``), the continuous Riccati solution of the true linearisation at x_eq with Q = qI,
    R = rI (``terminal='lqr'``, the LQR cost-to-go), or a given (n, n) matrix.  From ``config`` (an LmpcConfig or
    anything with ``free_moves``/``blocks``) only the move blocking is used; the horizon is ``horizon_steps``.
    z0 is unused; ``region`` is 'n/a' unless a ``clf`` is given (then it is computed from z0, with no constraint).
    On an IPOPT failure the step falls back to ``law(z0)`` if a law is given, else to the saturated LQR feedback.
    The first guess after a reset is ``init``'s: 'lqr' (the default), the saturated LQR feedback rolled out on the
    true system, or 'zero' inputs (kexp before issue 35: from zero inputs a 3-s horizon lets the cart pendulum fall
    first, and both solvers then stay with plans that swing it through — J 38–46 where the LQR guess gives 1.41).
    :class:`~kexp.control.sqp_oracle.SqpOracle` solves the same problem with kexp's compiled SQP.
    """

    solver = "ipopt"
    solver_label = "IPOPT"

    def __init__(self, system, config=None, u_min=-5.0, u_max=5.0, horizon_steps: int = 20, dt: float = 0.01,
                 q: float = 1.0, r: float = 1.0, terminal="lqr", *, substeps: int = 4, clf=None, law=None,
                 ipopt_tol: float = 1e-8, ipopt_max_iter: int = 500, ipopt_options: dict | None = None,
                 record_prediction: bool = False, init: str = "lqr"):
        ca = _casadi()
        self._setup(system, config, u_min, u_max, horizon_steps, dt, q, r, terminal, substeps, clf, law,
                    record_prediction, init)
        Xt = self.terminal_matrix
        f, self.model_source = symbolic_dynamics(system, with_source=True)
        xs = ca.SX.sym("x", self.n)
        us = ca.SX.sym("u", self.m)
        self.step_fn = ca.Function("true_step", [xs, us], [rk4_step(f, xs, us, self.dt, int(substeps))])

        n, m, N = self.n, self.m, self.N
        w = ca.SX.sym("w", self.nu + N * n)
        x0 = ca.SX.sym("x0", n)
        U = [w[i * m:(i + 1) * m] for i in range(self.nb)]
        X = [w[self.nu + j * n: self.nu + (j + 1) * n] for j in range(N)]
        xe = ca.DM(self.x_eq)
        cost, dyn, prev = 0, [], x0
        for j in range(N):
            dyn.append(self.step_fn(prev, U[self.bos[j]]) - X[j])
            cost = cost + self.dt * q * ca.sumsqr(X[j] - xe)
            prev = X[j]
        for i in range(self.nb):
            cost = cost + self.dt * r * float(self.sizes[i]) * ca.sumsqr(U[i])
        if np.any(Xt != 0):
            cost = cost + ca.dot(X[-1] - xe, ca.mtimes(ca.DM(Xt), X[-1] - xe))
        self._solver = ca.nlpsol("nmpc_oracle", "ipopt", {"x": w, "p": x0, "f": cost, "g": ca.vertcat(*dyn)},
                                 _ipopt_options(ipopt_tol, ipopt_max_iter, ipopt_options))
        self._lbx = np.concatenate([np.tile(self.u_min, self.nb), np.full(N * n, -np.inf)])
        self._ubx = np.concatenate([np.tile(self.u_max, self.nb), np.full(N * n, np.inf)])
        self._g0 = np.zeros(N * n)
        self.reset()

    def _one_step(self, x, u) -> np.ndarray:
        return np.asarray(self.step_fn(x, u), float).reshape(-1)

    def simulate(self, x0, U) -> np.ndarray:
        """The oracle's own prediction (N+1, n) for block inputs U (nb, m)."""
        X = np.empty((self.N + 1, self.n))
        X[0] = x0
        for j in range(self.N):
            X[j + 1] = np.asarray(self.step_fn(X[j], U[self.bos[j]]), float).reshape(-1)
        return X

    def step(self, x0: np.ndarray, z0: np.ndarray | None = None) -> ControlStep:
        t0 = time.perf_counter()
        x0 = np.asarray(x0, float)
        region = self._region(z0)
        if not np.all(np.isfinite(x0)):
            return self._fallback(x0, z0, "non-finite state x", region, t0, "not_run", 0)
        Ubar = self._first_guess(x0)
        Xbar = self.simulate(x0, Ubar)
        if not np.all(np.isfinite(Xbar)):
            Xbar = np.tile(x0, (self.N + 1, 1))
        w0 = np.concatenate([Ubar.reshape(-1), Xbar[1:].reshape(-1)])
        sol, status, iters, why = _solve(self._solver, dict(x0=w0, p=x0, lbx=self._lbx, ubx=self._ubx,
                                                            lbg=self._g0, ubg=self._g0))
        if sol is None:
            return self._fallback(x0, z0, why, region, t0, status, iters)
        wopt = np.asarray(sol["x"], float).reshape(-1)
        U = np.clip(wopt[: self.nu].reshape(self.nb, self.m), self.u_min, self.u_max)
        self._keep_plan(U, float(sol["f"]))
        pred = None
        if self.record_prediction:   # note: x (N+1, n) here, not z
            pred = np.vstack([x0, wopt[self.nu:].reshape(self.N, self.n)])
        return ControlStep(u=U[0].copy(), status="solved", qp_status=status, iterations=iters, qp_iterations=iters,
                           solve_time=time.perf_counter() - t0, region=region, active="none", binds=False,
                           slack=0.0, fallback=False, reason="", predicted=pred)
