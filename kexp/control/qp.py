"""A guarded dense QP on PIQP:  min ½xᵀHx + gᵀx  s.t.  Gx ≤ h_u,  x_l ≤ x ≤ x_u.

PIQP only prints invalid input to ``setup()``/``update()`` and a following ``solve()`` can crash the process
(design §3), so every array is checked for shape and finiteness here first.  The structure (sizes) is fixed at
construction; every solve returns a :class:`QpResult` with a status, never None.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import piqp

from ..errors import ConfigError


@dataclass(frozen=True)
class QpResult:
    x: np.ndarray
    status: str          # 'solved' or PIQP's status name, or 'invalid_input: …'
    success: bool
    iterations: int
    solve_time: float    # seconds, wall clock around the solver call
    message: str = ""


class DenseQp:
    def __init__(self, n: int, n_ineq: int, *, eps: float = 1e-8, max_iter: int = 100):
        if n < 1 or n_ineq < 0:
            raise ConfigError(f"QP sizes n={n}, n_ineq={n_ineq} are invalid")
        self.n, self.n_ineq = n, n_ineq
        self.eps, self.max_iter = eps, max_iter
        self._solver = None

    def _check(self, H, g, G, h_u, x_l, x_u) -> str:
        shapes = {"H": (H, (self.n, self.n)), "g": (g, (self.n,)), "G": (G, (self.n_ineq, self.n)),
                  "h_u": (h_u, (self.n_ineq,)), "x_l": (x_l, (self.n,)), "x_u": (x_u, (self.n,))}
        for name, (arr, shape) in shapes.items():
            if arr.shape != shape:
                return f"{name} has shape {arr.shape}, expected {shape}"
        for name in ("H", "g", "G", "h_u"):
            if not np.isfinite(shapes[name][0]).all():
                return f"{name} contains NaN/inf"
        if np.isnan(x_l).any() or np.isnan(x_u).any() or (x_l > x_u).any():
            return "bounds x_l > x_u or NaN"
        return ""

    def solve(self, H, g, G, h_u, x_l, x_u) -> QpResult:
        H = np.asfortranarray(H, dtype=float)
        g = np.ascontiguousarray(g, dtype=float)
        G = np.asfortranarray(G, dtype=float)
        h_u = np.ascontiguousarray(h_u, dtype=float)
        x_l = np.ascontiguousarray(x_l, dtype=float)
        x_u = np.ascontiguousarray(x_u, dtype=float)
        problem = self._check(H, g, G, h_u, x_l, x_u)
        if problem:
            return QpResult(np.full(self.n, np.nan), f"invalid_input: {problem}", False, 0, 0.0, problem)
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
        elif np.array_equal(x_l, self._bounds[0]) and np.array_equal(x_u, self._bounds[1]):
            self._solver.update(P=H, c=g, G=G, h_u=h_u)      # h_l = −∞ and the bounds are as set up
        else:
            self._solver.update(P=H, c=g, G=G, h_u=h_u, x_l=x_l, x_u=x_u)
            self._bounds = (x_l.copy(), x_u.copy())
        status = self._solver.solve()
        dt = time.perf_counter() - t0
        res = self._solver.result
        x = np.array(res.x, dtype=float)
        ok = status == piqp.PIQP_SOLVED and np.all(np.isfinite(x))
        name = "solved" if ok else str(status).split(".")[-1]
        return QpResult(x, name, bool(ok), int(res.info.iter), dt, "" if ok else f"PIQP: {name}")
