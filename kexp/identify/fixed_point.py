"""The equilibrium as a fixed point of the fitted operator.

x_eq is an equilibrium of the unforced system, so every dictionary function is constant along it: φ(x_eq) is
mapped to itself, K φ(x_eq) = φ(x_eq), exactly.  Least squares does not know this: with a constant in the
dictionary (or an intercept column) the fit's one-step map moves x_eq by its truncation error, the eigen-
functions are then not zero at x_eq, and the controller's model, shifted so that z = 0 at x_eq, drops a drift
ΛΨ(x_eq) that the fit had (measured on the paper's Van der Pol recipe at 10⁴ pairs: ‖ΛΨ(x_eq)‖ = 70.9 and a
1-s prediction error 0.90 instead of the fit's 0.43).  Imposing the fixed point as an equality constraint makes
every eigenfunction with λ̃ ≠ 1 vanish at x_eq (λ̃ ψ(x_eq) = wᵀKφ(x_eq) = ψ(x_eq)), so the shifted model drops
nothing: it *is* the constrained fit.

The constrained problem min ‖L X − R‖ s.t. aᵀX = bᵀ is solved exactly in a's orthogonal complement:
X = a bᵀ/‖a‖² + Q Y with Q (columns 2… of the Householder reflector of a) and Y the unconstrained least squares
of L Q Y ≈ R − L a bᵀ/‖a‖², with the fit's own rcond.  When a = 0 (a dictionary without a constant centred at
x_eq: φ(x_eq) = 0) the constraint is empty and the plain solve runs, bit for bit.
"""
from __future__ import annotations

from typing import Callable

import numpy as np


def householder_complement(a: np.ndarray) -> np.ndarray:
    """(P, P−1) orthonormal columns spanning the orthogonal complement of the nonzero vector a (P,)."""
    a = np.asarray(a, dtype=float)
    v = a / np.linalg.norm(a)
    v = v.copy()
    v[0] += 1.0 if v[0] >= 0 else -1.0      # no cancellation: v = a/‖a‖ + sign(a₀) e₀
    H = np.eye(a.size) - np.outer(v, v) / (v @ v) * 2.0
    return H[:, 1:]


def solve_fixed_point(solve: Callable[[np.ndarray, np.ndarray], np.ndarray], lhs: np.ndarray, rhs: np.ndarray,
                      a: np.ndarray | None, b: np.ndarray | None) -> np.ndarray:
    """min ‖lhs X − rhs‖ subject to aᵀX = bᵀ (lhs (r, P), rhs (r, N), a (P,), b (N,)); ``solve(lhs, rhs)`` is the
    fit's least-squares solve.  a None or zero: the unconstrained solve (then b must be zero too)."""
    if a is None or not np.any(a):
        if b is not None and np.any(b):
            raise ValueError("fixed-point constraint 0ᵀX = b with b ≠ 0 is infeasible")
        return solve(lhs, rhs)
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    particular = np.outer(a, b) / (a @ a)
    Q = householder_complement(a)
    Y = solve(lhs @ Q, rhs - lhs @ particular)
    return particular + Q @ Y
