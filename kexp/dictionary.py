"""Dictionaries of observables φ: ℝⁿ → ℝᴺ with analytic Jacobians.

Arrays are batch-first: ``x`` has shape (M, n); :meth:`Monomials.lift` returns (M, N), :meth:`Monomials.jacobian`
returns (M, N, n), :meth:`Monomials.lie` returns (M, N) for one vector field or (M, N, m) for m of them.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from .data.checks import items
from .errors import ConfigError, is_number

MAX_FUNCTIONS = 5000


def monomial_exponents(n: int, degree: int, *, include_constant: bool = True,
                       weights: tuple[int, ...] | None = None) -> np.ndarray:
    """Exponents α (rows, shape (N, n)) with Σ w_i α_i ≤ degree, graded then lexicographic with x1 first:
    n = 2, degree 2 → [1, x1, x2, x1², x1x2, x2²]."""
    w = np.ones(n, dtype=int) if weights is None else np.asarray(weights, dtype=int)
    rows = []
    for total in range(0 if include_constant else 1, degree + 1):
        # all α with Σ α_i = total (ordinary degree), in lexicographic order, x1 power descending
        for combo in itertools.combinations_with_replacement(range(n), total):
            alpha = np.bincount(np.asarray(combo, dtype=int), minlength=n) if combo else np.zeros(n, dtype=int)
            if int(alpha @ w) <= degree:
                rows.append(alpha)
    return np.array(rows, dtype=int).reshape(-1, n)


@dataclass(frozen=True)
class Monomials:
    """Monomials of the centred, scaled state ξ = (x − center)/scale up to (weighted) degree ``degree``.

    ``weights`` (default all 1) gives a weighted degree Σ w_i α_i ≤ degree, useful where a Koopman-invariant
    subspace is known (e.g. weights (1, 2) for the slow-manifold system).  ``scale`` (default 1) keeps
    high powers of large states from ruining the conditioning of the fit.  ``center`` (default the origin; the
    app centres on the system's equilibrium) makes the dictionary the same about x_eq wherever x_eq lies: without
    the constant, monomials of x and of x − x_eq span different spaces, and high powers of a far x_eq ruin the
    conditioning as a large scale does.
    """

    n: int
    degree: int
    include_constant: bool = True
    weights: tuple[int, ...] | None = None
    scale: tuple[float, ...] | None = None
    center: tuple[float, ...] | None = None
    exponents: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        if not (is_number(self.n, integer=True) and self.n >= 1):
            raise ConfigError(f"dictionary.n={self.n!r}: the state dimension must be an int >= 1")
        if not (is_number(self.degree, integer=True) and self.degree >= 1):
            raise ConfigError(f"dictionary.degree={self.degree!r}: use an int >= 1")
        if not isinstance(self.include_constant, (bool, np.bool_)):
            raise ConfigError(f"dictionary.include_constant={self.include_constant!r}: use true or false")
        if self.weights is not None:
            w = self.weights
            if isinstance(w, (str, bytes)) or not np.iterable(w) or not all(is_number(v, integer=True) for v in w):
                raise ConfigError(f"dictionary.weights={w!r}: give {self.n} ints >= 1, or null")
            w = tuple(int(v) for v in w)
            if len(w) != self.n or min(w) < 1:
                raise ConfigError(f"dictionary.weights={self.weights!r}: give {self.n} positive ints")
            object.__setattr__(self, "weights", w)
        if self.scale is not None:
            try:
                raw = np.asarray(self.scale)
                ok = raw.dtype.kind in "iuf" and raw.ndim <= 1
            except (ValueError, TypeError):
                ok = False
            if not ok:
                raise ConfigError(f"dictionary.scale={self.scale!r}: give a number or {self.n} numbers, or null")
            s = tuple(float(v) for v in np.atleast_1d(self.scale))
            if len(s) == 1:
                s = s * self.n
            if len(s) != self.n or not all(np.isfinite(v) and v > 0 for v in s):
                raise ConfigError(f"dictionary.scale={self.scale!r}: give {self.n} finite positive numbers")
            object.__setattr__(self, "scale", s)
        if self.center is not None:
            values = items(self.center)   # a number or a flat list of numbers (not bools, not strings)
            if not values or len(values) not in (1, self.n) or not np.all(np.isfinite(values)):
                raise ConfigError(f"dictionary.center={self.center!r}: give {self.n} finite numbers (or one for "
                                  "all states), or null (the origin)")
            c = tuple(float(v) for v in values)
            object.__setattr__(self, "center", c * self.n if len(c) == 1 else c)
        from math import comb
        n_max = comb(self.n + self.degree, self.degree)
        if self.weights is None and n_max > MAX_FUNCTIONS:
            raise ConfigError(f"dictionary.degree={self.degree} with n={self.n} states gives {n_max} monomials "
                              f"(limit {MAX_FUNCTIONS}); lower the degree")
        e = monomial_exponents(self.n, self.degree, include_constant=self.include_constant, weights=self.weights)
        e.setflags(write=False)
        object.__setattr__(self, "exponents", e)

    # ------------------------------------------------------------------------------------------------
    @property
    def size(self) -> int:
        return self.exponents.shape[0]

    @property
    def constant_index(self) -> int | None:
        return 0 if self.include_constant else None

    @property
    def linear_indices(self) -> np.ndarray:
        """Index of x_i (first-degree monomial) for each state i."""
        idx = np.empty(self.n, dtype=int)
        for i in range(self.n):
            e = np.zeros(self.n, dtype=int)
            e[i] = 1
            idx[i] = int(np.flatnonzero((self.exponents == e).all(axis=1))[0])
        return idx

    @property
    def _scale(self) -> np.ndarray:
        return np.ones(self.n) if self.scale is None else np.asarray(self.scale)

    def _xi(self, x: np.ndarray) -> np.ndarray:
        """ξ = (x − center)/scale: (M, n) -> (M, n)."""
        return (x if self.center is None else x - np.asarray(self.center)) / self._scale

    def names(self, state_names: tuple[str, ...] | None = None) -> list[str]:
        s = state_names or tuple(f"x{i + 1}" for i in range(self.n))
        out = []
        for alpha in self.exponents:
            parts = [s[i] + (f"^{a}" if a > 1 else "") for i, a in enumerate(alpha) if a > 0]
            out.append("*".join(parts) if parts else "1")
        return out

    def _powers(self, xi: np.ndarray) -> np.ndarray:
        """xi (M, n) -> table P (n, degree+1, M) with P[i, k] = xi_i^k."""
        d = int(self.exponents.max()) if self.exponents.size else 0
        p = np.empty((self.n, d + 1, xi.shape[0]))
        p[:, 0] = 1.0
        for k in range(1, d + 1):
            p[:, k] = p[:, k - 1] * xi.T
        return p

    def _check_x(self, x) -> np.ndarray:
        try:
            x = np.asarray(x, dtype=float)
        except (ValueError, TypeError):
            raise ConfigError(f"dictionary expects states of shape (M, {self.n}) of numbers, got {x!r:.80}") from None
        if x.ndim == 1:
            x = x[None]
        if x.ndim != 2 or x.shape[1] != self.n:
            raise ConfigError(f"dictionary expects states of shape (M, {self.n}), got {x.shape}")
        return x

    def lift(self, x: np.ndarray) -> np.ndarray:
        """φ(x): (M, n) -> (M, N)."""
        x = self._check_x(x)
        if x.shape[0] == 1:
            return self._lift_one(x[0])[None]
        p = self._powers(self._xi(x))
        out = np.ones((x.shape[0], self.size))
        for i in range(self.n):
            out *= p[i, self.exponents[:, i]].T
        return out

    def _lift_one(self, x: np.ndarray) -> np.ndarray:
        """φ at one state (the closed loop lifts one per step): the same multiplications as the batched path, in
        the same order, on Python floats (IEEE doubles: bit-identical, a test), without its ~20 numpy calls."""
        tables = self.__dict__.get("_one_state")
        if tables is None:   # once per instance (not in __post_init__: an unpickled instance skips it)
            e = self.exponents
            tables = (tuple(tuple(r) for r in e.tolist()), int(e.max()) if e.size else 0,
                      self.scale or (1.0,) * self.n, self.center)
            object.__setattr__(self, "_one_state", tables)
        rows, d, scales, center = tables
        x = x.tolist() if center is None else [xi - ci for xi, ci in zip(x.tolist(), center)]
        powers = []
        for xi, si in zip(x, scales):
            xi = xi / si
            pw = [1.0]
            for _ in range(d):
                pw.append(pw[-1] * xi)
            powers.append(pw)
        out = []
        for row in rows:
            v = 1.0
            for pw, a in zip(powers, row):
                v *= pw[a]
            out.append(v)
        return np.array(out)

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """∂φ/∂x: (M, n) -> (M, N, n)."""
        x = self._check_x(x)
        p = self._powers(self._xi(x))
        factors = np.stack([p[i, self.exponents[:, i]].T for i in range(self.n)], axis=-1)  # (M, N, n)
        jac = np.empty((x.shape[0], self.size, self.n))
        for i in range(self.n):
            a = self.exponents[:, i]
            d = (a * p[i, np.maximum(a - 1, 0)].T) / self._scale[i]  # ∂(ξ_i^a)/∂x_i
            others = np.prod(np.delete(factors, i, axis=-1), axis=-1)
            jac[..., i] = d * others
        return jac

    def lie(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Lie derivative (∂φ/∂x)·v for vector-field values ``v`` (M, n) -> (M, N), or (M, n, m) -> (M, N, m)."""
        jac = self.jacobian(x)
        v = np.asarray(v, dtype=float)
        if v.ndim == 2:
            return np.einsum("knj,kj->kn", jac, v)
        return np.einsum("knj,kjm->knm", jac, v)

    def spec(self) -> dict:
        return {"kind": "monomials", "n": int(self.n), "degree": int(self.degree),
                "include_constant": bool(self.include_constant),
                "weights": None if self.weights is None else list(self.weights),
                "scale": None if self.scale is None else list(self.scale),
                "center": None if self.center is None else list(self.center)}

    @classmethod
    def from_spec(cls, spec: dict) -> "Monomials":
        if spec.get("kind") != "monomials":
            raise ConfigError(f"dictionary kind {spec.get('kind')!r} is unknown; valid: 'monomials'")
        return cls(n=spec["n"], degree=spec["degree"], include_constant=spec["include_constant"],
                   weights=None if spec["weights"] is None else tuple(spec["weights"]),
                   scale=None if spec["scale"] is None else tuple(spec["scale"]),
                   center=None if spec.get("center") is None else tuple(spec["center"]))   # no key: saved uncentred
