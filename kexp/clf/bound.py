"""Does V = zᵀPz, z = Ψ(x) − Ψ(x_eq), bound the state?  A decrease of V says nothing about x unless it does.

Over the certificate's sampled states x of the region (the box region_low .. region_high around x_eq):

* ``c`` = min V(x)/‖x − x_eq‖² (Euclidean, in V's units per squared state unit) and the unit direction
  (x − x_eq)/‖x − x_eq‖ of its minimiser: where V is flattest.  V(x) ≥ c‖x − x_eq‖² on the samples, so a
  decrease of V from x0 keeps ‖x − x_eq‖ ≤ sqrt(V(x0)/c) while x stays in the region.
* ``c_local`` = λ_min(JᵀPJ), J = ∂z/∂x at x_eq, with its unit eigenvector: the same at x_eq (V ≈ δxᵀJᵀPJδx).
* ``gain`` γ: the same bound in the region's own scale, so that neither V's scale nor the states' units matter.
  Each deviation is divided by the region's extent on its side (x̃_i = (x − x_eq)_i / high_i where it is ≥ 0,
  / (−low_i) where it is < 0: the box becomes [−1, 1]ⁿ).  With q(x) = V(x)/‖x̃‖², γ = sqrt(max q / min q) over
  the samples.  A decrease of V from x0 keeps ‖x̃(t)‖ ≤ sqrt(V(x0)/min q) ≤ γ‖x̃0‖: every state with
  ‖x̃0‖ < 1/γ stays inside the unit ball of x̃, which lies in the region (and inside it the certificate's
  sampled V̇ applies).  γ = 1 for a V round in the region's scale, sqrt(condition number) for a quadratic V.
* ``holds`` = γ ≤ :data:`GAIN_MAX` (20): a decrease of V keeps in the region at least the states within 5 % of
  it around x_eq (one grid step at the default 41 points per axis).  Otherwise V is nearly blind to some
  direction of x (c too small against V's size elsewhere) and the certificate says "not a CLF in x", whatever
  the decrease.  Not lower: the SDP's bounds alone (c_upper/c_lower = 100) allow γ = 10 on a lift that is
  round in x.

Measured (grid 41² or 20000 samples, the presets' regions): γ = 1.21 vanderpol, 1.37 pendulum, 2.02
paper_vanderpol (the default), 3.59 cart_pendulum, 4.02 paper_pendulum, 4.34 duffing, 8.43 cartpole4.  A linear
system with an unstable mode λ (ẋ1 = λx1 + 0.2u, ẋ2 = −x2 + u), identified from 10-s runs that grew along it
(eigen-coordinates at unit RMS, the paper's SDP): γ = 37, 50, 103, 228, 1269 for λ = 0.05, 0.1, 0.2, 0.3, 0.5;
under Sontag's h from four starts in the region, |x1| left the region [−1, 1]² (its maximum over 20 s: 2.3, 6.3,
47, 346, 18 800), and at λ = 0.5 V had fallen 3–4 decades when |x1| passed 13.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

GAIN_MAX = 20.0   # V bounds the state when γ ≤ this: the states within 1/GAIN_MAX of the region stay in it


@dataclass(frozen=True)
class StateBound:
    """What :func:`state_bound` found (see the module text): ``c`` (≥ 0) and ``direction`` (n,) unit, over the
    samples; ``c_local`` and ``direction_local`` (n,) unit, at x_eq; ``gain`` γ ≥ 1 (inf when V vanishes at a
    sampled x ≠ x_eq); ``holds`` = γ ≤ :data:`GAIN_MAX`.  Directions have their largest entry positive."""

    c: float
    direction: tuple[float, ...]
    c_local: float
    direction_local: tuple[float, ...]
    gain: float
    holds: bool


def _signed(v: np.ndarray) -> tuple[float, ...]:
    """v with its largest-magnitude entry (the first of equals) made positive: ±v name one direction."""
    v = np.asarray(v, dtype=float)
    return tuple(float(a) + 0.0 for a in (v if v[np.argmax(np.abs(v))] >= 0 else -v))   # + 0.0: no -0.0


def region_scaled(dx: np.ndarray, low, high) -> np.ndarray:
    """Deviations ``dx`` (M, n) from x_eq divided, per coordinate, by the region's extent on their side: high_i
    for dx_i ≥ 0, −low_i for dx_i < 0 (``low`` ≤ 0 ≤ ``high``, numbers or (n,)).  The box low..high becomes
    [−1, 1]ⁿ.  A side of extent 0 holds no deviation but 0, which stays 0."""
    dx = np.asarray(dx, dtype=float)
    n = dx.shape[-1]
    lo = np.broadcast_to(np.asarray(low, dtype=float), (n,))
    hi = np.broadcast_to(np.asarray(high, dtype=float), (n,))
    side = np.where(dx >= 0, hi, -lo)
    return np.divide(dx, side, out=np.zeros_like(dx), where=side > 0)


def state_bound(model, lyap, x: np.ndarray, V: np.ndarray, low, high) -> StateBound:
    """The bound of the sampled states ``x`` (M, n), none at x_eq, with their values ``V`` (M,) =
    ``lyap.value(model.lift(x))``, over the box ``low`` .. ``high`` of x − x_eq (ClfConfig's region)."""
    d = np.asarray(x, dtype=float) - model.x_eq
    r2 = np.sum(d * d, axis=1)
    q = V / r2
    i = int(np.argmin(q))
    J = model.lift_jacobian(model.x_eq[None])[0]                     # (k, n)
    H = J.T @ lyap.P @ J
    w, vec = np.linalg.eigh(0.5 * (H + H.T))
    s = region_scaled(d, low, high)
    qs = V / np.sum(s * s, axis=1)
    lo_q, hi_q = float(qs.min()), float(qs.max())
    gain = float(np.sqrt(hi_q / lo_q)) if lo_q > 0 else float("inf")
    return StateBound(c=float(q[i]), direction=_signed(d[i] / np.sqrt(r2[i])), c_local=float(w[0]),
                      direction_local=_signed(vec[:, 0]), gain=gain, holds=bool(gain <= GAIN_MAX))
