"""Explicit stabilising laws h(z) on a quadratic Lyapunov function, vectorised over states.

Every law maps z (..., k) to u (..., m), always finite and within [u_min, u_max] (componentwise clip);
``law.single(z, a, beta)`` is the same for one state z (k,) given its L_ΛV and L_BV (the control step's path).
- ``sontag``: Sontag's formula (paper eq. 19), multi-input form
  b(z) = −(a + √(a² + ‖β‖⁴)) / ‖β‖² · β  (0 where β = 0), with a = L_ΛV, β = L_BV; then saturated.
- ``lie_gain``: h(z) = −k·L_BV(z), saturated (the paper's pendulum law; no decay guarantee).
- ``model_lqr``: h(z) = −K_x·Cz, saturated: the LQR gain of the identified model's own linearisation (the same
  Riccati solution as ``clf.method=lqr_x``; Cz ≈ x − x_eq).  No decay guarantee far from x_eq, but it is the law
  LQR would apply, so the LMPC's (21f) no longer asks for more decrease than LQR gives.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..clf.lyapunov import QuadraticLyapunov
from ..errors import ConfigError, require_number
from .checks import input_bounds


def _bounds(u_min, u_max, m):
    lo, hi = input_bounds(u_min, u_max, m)
    lo.setflags(write=False)
    hi.setflags(write=False)
    return lo, hi


@dataclass(frozen=True, eq=False)
class Sontag:
    """Sontag's formula (paper eq. 19) on V = zᵀPz (``lyap``), saturated to [``u_min``, ``u_max``] (scalars or
    (m,), broadcast and stored as read-only (m,) arrays).  ``law(z)``: z (..., k) -> u (..., m), finite and within
    the bounds; ``unsaturated(z)`` the formula before the clip (0 where |L_BV|² ≤ ``eps``·max(1, |L_ΛV|)).
    Raises :class:`~kexp.errors.ConfigError` unless u_min < u_max, both finite, and ``eps`` is finite and >= 0."""

    lyap: QuadraticLyapunov
    u_min: np.ndarray
    u_max: np.ndarray
    eps: float = 1e-14

    name = "sontag"

    def __post_init__(self):
        require_number(self.eps, "controller.law_params.eps")
        if not (self.eps >= 0 and np.isfinite(self.eps)):
            raise ConfigError(f"controller.law_params.eps={self.eps}: use a finite threshold >= 0 (default 1e-14)")
        lo, hi = _bounds(self.u_min, self.u_max, self.lyap.m)
        object.__setattr__(self, "u_min", lo)
        object.__setattr__(self, "u_max", hi)

    def unsaturated(self, z: np.ndarray) -> np.ndarray:
        a, beta = self.lyap.lie(z)
        nb2 = np.sum(beta * beta, axis=-1)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            coef = -(a + np.sqrt(a * a + nb2 * nb2)) / nb2
        coef = np.where(nb2 > self.eps * np.maximum(1.0, np.abs(a)), coef, 0.0)
        u = coef[..., None] * beta
        return np.where(np.isfinite(u), u, 0.0)

    def __call__(self, z: np.ndarray) -> np.ndarray:
        return np.clip(self.unsaturated(z), self.u_min, self.u_max)

    def single(self, z: np.ndarray, a: float, beta: np.ndarray) -> np.ndarray:
        """h at one state z (k,) given its L_ΛV = ``a`` and L_BV = ``beta`` (m,) (:meth:`QuadraticLyapunov.at`):
        the same formula as ``law(z[None])[0]`` without the batch machinery (a control step calls it once)."""
        nb2 = float(beta @ beta)
        if not nb2 > self.eps * max(1.0, abs(a)):
            return np.clip(np.zeros_like(beta), self.u_min, self.u_max)
        u = (-(a + np.sqrt(a * a + nb2 * nb2)) / nb2) * beta
        return np.minimum(np.maximum(np.where(np.isfinite(u), u, 0.0), self.u_min), self.u_max)   # = np.clip


@dataclass(frozen=True, eq=False)
class LieGain:
    """h(z) = −k·L_BV(z) on V = zᵀPz (``lyap``), saturated to [``u_min``, ``u_max``] (the paper's pendulum law;
    no decay guarantee).  ``law(z)``: z (..., k) -> u (..., m), finite and within the bounds.  Raises
    :class:`~kexp.errors.ConfigError` for a gain ``k`` that is not finite and > 0 or bounds not u_min < u_max."""

    lyap: QuadraticLyapunov
    u_min: np.ndarray
    u_max: np.ndarray
    k: float = 10.0

    name = "lie_gain"

    def __post_init__(self):
        require_number(self.k, "controller.law_params.k")
        if not (np.isfinite(self.k) and self.k > 0):
            raise ConfigError(f"controller.law_params.k={self.k}: use a finite gain > 0")
        lo, hi = _bounds(self.u_min, self.u_max, self.lyap.m)
        object.__setattr__(self, "u_min", lo)
        object.__setattr__(self, "u_max", hi)

    def __call__(self, z: np.ndarray) -> np.ndarray:
        _, beta = self.lyap.lie(z)
        u = np.where(np.isfinite(beta), -self.k * beta, 0.0)
        return np.clip(u, self.u_min, self.u_max)

    def single(self, z: np.ndarray, a: float, beta: np.ndarray) -> np.ndarray:
        """h at one state z (k,) given its L_BV = ``beta`` (m,) (``a`` unused): ``law(z[None])[0]``, unbatched."""
        return np.minimum(np.maximum(np.where(np.isfinite(beta), -self.k * beta, 0.0), self.u_min),
                          self.u_max)   # = np.clip


@dataclass(frozen=True, eq=False)
class ModelLqrGain:
    """h(z) = −K·z with K (m, k) = K_x·C, saturated to [``u_min``, ``u_max``]: the LQR law of the identified
    model's linearisation, u = −K_x(x − x_eq) with x − x_eq ≈ Cz.  Build it with :func:`make_law` ('model_lqr',
    given the model and the Riccati weights) so that K_x is the Riccati solution the lqr_x CLF uses.
    ``law(z)``: z (..., k) -> u (..., m), finite and within the bounds.  Raises
    :class:`~kexp.errors.ConfigError` for a K that does not fit ``lyap`` or is not finite."""

    lyap: QuadraticLyapunov
    u_min: np.ndarray
    u_max: np.ndarray
    K: np.ndarray

    name = "model_lqr"

    def __post_init__(self):
        K = np.array(self.K, dtype=float)
        k = self.lyap.P.shape[0]
        if K.shape != (self.lyap.m, k) or not np.all(np.isfinite(K)):
            raise ConfigError(f"model_lqr law: K must be finite with shape ({self.lyap.m}, {k}), got {K.shape}")
        K.setflags(write=False)
        lo, hi = _bounds(self.u_min, self.u_max, self.lyap.m)
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "u_min", lo)
        object.__setattr__(self, "u_max", hi)

    def __call__(self, z: np.ndarray) -> np.ndarray:
        u = -(np.asarray(z, dtype=float) @ self.K.T)
        return np.clip(np.where(np.isfinite(u), u, 0.0), self.u_min, self.u_max)

    def single(self, z: np.ndarray, a: float, beta: np.ndarray) -> np.ndarray:
        """h at one state z (k,) (``a``, ``beta`` unused): ``law(z[None])[0]``, unbatched."""
        u = -(self.K @ np.asarray(z, dtype=float))
        return np.minimum(np.maximum(np.where(np.isfinite(u), u, 0.0), self.u_min), self.u_max)   # = np.clip


LAWS = {"sontag": Sontag, "lie_gain": LieGain, "model_lqr": ModelLqrGain}


def make_law(name: str, lyap: QuadraticLyapunov, u_min, u_max, *, model=None, weights=(1.0, 1.0), **params):
    """The explicit law ``name`` ('sontag', 'lie_gain' or 'model_lqr', see :data:`LAWS`) on ``lyap`` with input
    bounds ``u_min``, ``u_max`` (scalars or (m,)) and the law's own keyword ``params`` (``eps`` for sontag, ``k``
    for lie_gain).  'model_lqr' needs the identified ``model`` and the Riccati ``weights`` (q_x, r_u) — pass the
    CLF config's, so that the gain comes from the same Riccati solution as the lqr_x CLF.  Returns a callable
    z (..., k) -> u (..., m).  Raises :class:`~kexp.errors.ConfigError` for an unknown name, a ``lyap`` that is not a
    QuadraticLyapunov, bounds that are not finite u_min < u_max (a number or m numbers each), bad parameters or
    ``weights`` that are not two numbers, and
    :class:`~kexp.errors.ClfError` when the model's linearisation is not stabilisable."""
    if not (isinstance(name, str) and name in LAWS):
        raise ConfigError(f"explicit law {name!r} is unknown; valid: {sorted(LAWS)}")
    if not isinstance(lyap, QuadraticLyapunov):
        raise ConfigError(f"law {name!r}: lyap={type(lyap).__name__}: pass the CLF's V (clf.lyap, a "
                          "QuadraticLyapunov)")
    if name == "model_lqr":
        if params:
            raise ConfigError(f"law 'model_lqr' takes no law_params (got {params}); its weights are clf.q_x, "
                              "clf.r_u")
        if model is None:
            raise ConfigError("law 'model_lqr' needs the identified model")
        if not (isinstance(weights, (tuple, list, np.ndarray)) and len(weights) == 2):
            raise ConfigError(f"law 'model_lqr': weights={weights!r}: give (q_x, r_u), two finite numbers > 0")
        for key, value in zip(("clf.q_x", "clf.r_u"), weights):
            require_number(value, key)
        from ..clf.riccati import model_lqr
        lqr = model_lqr(model, *weights)
        return ModelLqrGain(lyap, u_min, u_max, K=lqr.K @ model.C)
    try:
        return LAWS[name](lyap, u_min, u_max, **params)
    except TypeError as exc:
        raise ConfigError(f"law {name!r}: bad parameters {params} ({exc})") from None
