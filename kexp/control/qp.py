"""A guarded dense QP:  min ½xᵀHx + gᵀx  s.t.  Gx ≤ h_u,  x_l ≤ x ≤ x_u, on kexp's compiled interior-point
solver (``solver='ipm'``, :mod:`kexp.control.ipm`), on DAQP (``solver='daqp'``, a dual active-set solver made for
MPC QPs: exact active sets, warm-started from the previous solve's) or on PIQP (``solver='piqp'``).

Every array is checked for shape and finiteness here first (PIQP only prints invalid input to ``setup()``/
``update()`` and a following ``solve()`` can crash the process, design §3).  The structure (sizes) is fixed at
construction; every solve returns a :class:`QpResult` with a status, never None.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import daqp
import numpy as np
import piqp
from numba import njit

from ..errors import ConfigError
from .ipm import MAX_ITER, SOLVED, STATUS_NAMES, solve_qp

SOLVERS = ("ipm", "daqp", "piqp")
# DAQP's exit flags (its include/constants.h): > 0 solved (2: solved with a soft constraint relaxed; kexp sets none)
DAQP_STATUS = {1: "solved", 2: "solved", -1: "primal_infeasible", -2: "cycling", -3: "unbounded",
               -4: "max_iter_reached", -5: "nonconvex", -6: "overdetermined_initial", -7: "time_limit",
               -8: "unsupported"}


@njit(cache=True)
def _all_finite(a) -> bool:
    for x in a.flat:
        if not np.isfinite(x):
            return False
    return True


@njit(cache=True)
def _scan(H, g, G, h_u, x_l, x_u, old_l, old_u) -> int:
    """One pass over the QP's data: 1–4 when H, g, G or h_u holds NaN/inf, 5 when a bound is NaN or x_l > x_u;
    else 0 if the bounds equal (old_l, old_u) and −1 if they differ (the LMPC's 21-variable QP: the whole check
    3 µs, against 23 µs for the numpy calls it replaced)."""
    if not _all_finite(H):
        return 1
    if not _all_finite(g):
        return 2
    if not _all_finite(G):
        return 3
    if not _all_finite(h_u):
        return 4
    same = old_l.shape[0] == x_l.shape[0]
    for i in range(x_l.shape[0]):
        lo, hi = x_l[i], x_u[i]
        if np.isnan(lo) or np.isnan(hi) or lo > hi:
            return 5
        if same and (lo != old_l[i] or hi != old_u[i]):
            same = False
    return 0 if same else -1


_SCAN_PROBLEM = {1: "H contains NaN/inf", 2: "g contains NaN/inf", 3: "G contains NaN/inf",
                 4: "h_u contains NaN/inf", 5: "bounds x_l > x_u or NaN"}


@dataclass(frozen=True)
class QpResult:
    x: np.ndarray
    status: str          # 'solved', the solver's status name, or 'invalid_input: …'
    success: bool
    iterations: int
    solve_time: float    # seconds, wall clock around the solver call
    message: str = ""


class DenseQp:
    """A QP of fixed sizes (n variables, n_ineq rows of G), solved again and again with new data.  ``eps`` is the
    convergence tolerance (absolute and relative), ``max_iter`` the iteration limit, ``solver`` 'ipm', 'daqp' or 'piqp'.
    The interior point that reaches ``max_iter`` solves again with its safeguard (another ``max_iter`` at most;
    the result's iterations count both passes).  DAQP: ``eps`` is its primal (constraint) tolerance, and as each
    of its iterations adds or drops one constraint its limit is at least 2·(n + n_ineq); each solve starts from the
    previous solve's active set (its workspace keeps it), except after a failure, which starts it afresh."""

    def __init__(self, n: int, n_ineq: int, *, eps: float = 1e-8, max_iter: int = 100, solver: str = "ipm"):
        if n < 1 or n_ineq < 0:
            raise ConfigError(f"QP sizes n={n}, n_ineq={n_ineq} are invalid")
        if solver not in SOLVERS:
            raise ConfigError(f"QP solver {solver!r}; valid: {SOLVERS}")
        self.n, self.n_ineq = n, n_ineq
        self.eps, self.max_iter, self.solver = eps, max_iter, solver
        self.solves = 0          # calls of solve() that reached the solver
        self._solver = None
        # compile (or load) the data check and the solver for the array layouts solve() passes them, now and not
        # in the first solve (on a fresh clone the check alone made a 0.3 s first control step)
        v = np.zeros(n)
        H0, G0 = np.eye(n, order="F"), np.zeros((n_ineq, n), order="F")
        _scan(H0, v, G0, np.zeros(n_ineq), v, v, v, v)
        if solver == "ipm":
            self._solve_ipm(H0, v, G0, np.ones(n_ineq), v - 1.0, v + 1.0)
        if solver == "daqp":   # DAQP's bounds: the n simple bounds, then the n_ineq rows (no lower bound on them)
            self._bu = np.zeros(n + n_ineq)
            self._bl = np.full(n + n_ineq, -np.inf)

    def _check(self, H, g, G, h_u, x_l, x_u) -> tuple[str, bool]:
        """(problem, bounds unchanged): the first thing wrong with the data ('' if nothing), and whether the
        bounds equal those PIQP or DAQP holds."""
        shapes = (("H", H, (self.n, self.n)), ("g", g, (self.n,)), ("G", G, (self.n_ineq, self.n)),
                  ("h_u", h_u, (self.n_ineq,)), ("x_l", x_l, (self.n,)), ("x_u", x_u, (self.n,)))
        for name, arr, shape in shapes:
            if arr.shape != shape:
                return f"{name} has shape {arr.shape}, expected {shape}", False
        old_l, old_u = self._bounds if self.solver != "ipm" and self._solver is not None else (x_l[:0], x_u[:0])
        code = _scan(H, g, G, h_u, x_l, x_u, old_l, old_u)
        return _SCAN_PROBLEM.get(code, ""), code == 0

    def solve(self, H, g, G, h_u, x_l, x_u, *, same_h: bool = False) -> QpResult:
        """``same_h``: H is the previous solve's, unchanged (DAQP then keeps its factorisation: an update of g and
        the bounds only; the other solvers ignore it)."""
        H = np.asfortranarray(H, dtype=float)
        g = np.ascontiguousarray(g, dtype=float)
        G = np.asfortranarray(G, dtype=float)
        h_u = np.ascontiguousarray(h_u, dtype=float)
        x_l = np.ascontiguousarray(x_l, dtype=float)
        x_u = np.ascontiguousarray(x_u, dtype=float)
        problem, same_bounds = self._check(H, g, G, h_u, x_l, x_u)
        if problem:
            return QpResult(np.full(self.n, np.nan), f"invalid_input: {problem}", False, 0, 0.0, problem)
        self.solves += 1
        if self.solver == "ipm":
            return self._solve_ipm(H, g, G, h_u, x_l, x_u)
        if self.solver == "daqp":
            return self._solve_daqp(H, g, G, h_u, x_l, x_u, same_bounds, same_h)
        t0 = time.perf_counter()
        if self._solver is None:
            s = piqp.DenseSolver()
            s.settings.eps_abs = self.eps
            s.settings.eps_rel = self.eps
            s.settings.max_iter = self.max_iter
            s.settings.verbose = False
            s.setup(H, g, None, None, G, np.full(self.n_ineq, -np.inf), h_u, x_l, x_u)
            self._solver = s
            self._bounds = (x_l.copy(), x_u.copy())
        elif same_bounds:
            self._solver.update(P=H, c=g, G=G, h_u=h_u)      # h_l = −∞ and the bounds are as set up
        else:
            self._solver.update(P=H, c=g, G=G, h_u=h_u, x_l=x_l, x_u=x_u)
            self._bounds = (x_l.copy(), x_u.copy())
        status = self._solver.solve()
        dt = time.perf_counter() - t0
        res = self._solver.result
        x = np.array(res.x, dtype=float)
        ok = status == piqp.PIQP_SOLVED and bool(np.isfinite(x).all())
        name = "solved" if ok else str(status).split(".")[-1]
        return QpResult(x, name, bool(ok), int(res.info.iter), dt, "" if ok else f"PIQP: {name}")

    def _solve_ipm(self, H, g, G, h_u, x_l, x_u) -> QpResult:
        # the IPM reads rows: H is symmetric, so its transpose (C-ordered when H is Fortran-ordered) is H itself
        H = H.T if not H.flags.c_contiguous else H
        G = np.ascontiguousarray(G)
        x = np.empty(self.n)
        t0 = time.perf_counter()
        code, iters = solve_qp(H, g, G, h_u, x_l, x_u, self.eps, self.max_iter, x, False)
        if code == MAX_ITER:     # plain Mehrotra cycled: again with the safeguard (kexp.control.ipm.solve_qp)
            code, more = solve_qp(H, g, G, h_u, x_l, x_u, self.eps, self.max_iter, x, True)
            iters += more
        dt = time.perf_counter() - t0
        ok = code == SOLVED
        name = STATUS_NAMES[code]
        return QpResult(x, name, ok, int(iters), dt, "" if ok else f"interior point: {name}")

    def _solve_daqp(self, H, g, G, h_u, x_l, x_u, same_bounds, same_h=False) -> QpResult:
        # DAQP reads rows (C order): H is symmetric, so the transpose of its Fortran-ordered array is H itself, and
        # a one-row G is both orders; the model keeps pointers to these arrays (no copy) until the next update
        H = None if same_h and self._solver is not None else H.T
        n = self.n
        A = G if self.n_ineq else None     # DAQP's update indexes a 0-row A out of bounds: give it none
        bu, bl = self._bu, self._bl
        bu[n:] = h_u
        t0 = time.perf_counter()
        model = self._solver
        if same_bounds:    # the simple bounds in bu and bl are those DAQP holds: only the rows' bounds change
            flag = model.update(H=H, f=g, A=A, bupper=bu)
        elif model is None:
            bu[:n] = x_u
            bl[:n] = x_l
            model = daqp.Model()
            model.settings = {"primal_tol": self.eps, "iter_limit": max(self.max_iter, 2 * (n + self.n_ineq))}
            flag, _ = model.setup(H, g, G, bu, bl)
            if flag >= 0:
                self._solver = model
                self._bounds = (x_l.copy(), x_u.copy())
        else:     # the working set of the last solve is kept: the warm start
            bu[:n] = x_u
            bl[:n] = x_l
            flag = model.update(H=H, f=g, A=A, bupper=bu, blower=bl)
            self._bounds = (x_l.copy(), x_u.copy())
        if flag < 0:       # H not positive definite (its factorisation failed) or the data refused
            self._solver = None
            name = "nonconvex" if flag == -5 else f"setup_failed_{flag}"
            return QpResult(np.full(n, np.nan), name, False, 0, time.perf_counter() - t0, f"DAQP: {name}")
        x, _, flag, info = model.solve()
        dt = time.perf_counter() - t0
        ok = flag > 0 and math.isfinite(x @ x)     # x @ x: NaN or inf if an entry is (0.3 µs, isfinite().all() 1.5)
        name = "solved" if ok else DAQP_STATUS.get(flag, f"exitflag_{flag}")
        if not ok:         # start the next solve from an empty working set, not from this one
            self._solver = None
        return QpResult(x, name, ok, int(info["iterations"]), dt, "" if ok else f"DAQP: {name}")
