"""The classic cart-pole as a user's own system: 4 states, one force input (kexp's "Your own system").

States x = (p, θ, v, ω): cart position [m], pole angle from upright [rad], cart velocity [m/s], pole angular
velocity [rad/s]; input u = the horizontal force on the cart [N].  Frictionless, a uniform pole of half-length l
(moment of inertia m·l²/3 about its centre), the equations of Barto, Sutton & Anderson (1983) as Gymnasium's
CartPole writes them, with the force kept as a free input:

    t = (u + m·l·ω²·sin θ)/(M + m)
    ω̇ = (g·sin θ − cos θ·t) / (l·(4/3 − m·cos²θ/(M + m)))
    v̇ = t − m·l·ω̇·cos θ/(M + m)

Both accelerations are affine in u, so ẋ = F(x) + G(x)·u with G varying with θ.  The upright equilibrium is the
origin; linearised there the pole has eigenvalues ±3.97 1/s (M = 1, m = 0.1, l = 0.5, g = 9.81) and the cart a
double integrator.  Run it with (from the repository's top folder)::

    PYTHONPATH=examples kexp +experiment=cartpole4 system.name=cartpole4:CartPole4
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from kexp.systems import ControlAffineSystem


@dataclass(frozen=True)
class CartPole4(ControlAffineSystem):
    """Cart-pole: cart mass ``M`` [kg], pole mass ``m`` [kg], pole half-length ``l`` [m], gravity ``g`` [m/s²]."""

    M: float = 1.0
    m_pole: float = 0.1
    l: float = 0.5
    g: float = 9.81
    name: ClassVar[str] = "cartpole4"
    n: ClassVar[int] = 4
    m: ClassVar[int] = 1
    constant_input_matrix: ClassVar[bool] = False

    @property
    def state_names(self):
        return ("p", "theta", "v", "omega")

    def _parts(self, x):
        """(sin θ, cos θ, 1/(M + m), 1/(l·(4/3 − m cos²θ/(M + m)))) for x (..., 4)."""
        th = np.asarray(x, dtype=float)[..., 1]
        s, c = np.sin(th), np.cos(th)
        inv_total = 1.0 / (self.M + self.m_pole)
        inv_den = 1.0 / (self.l * (4.0 / 3.0 - self.m_pole * c * c * inv_total))
        return s, c, inv_total, inv_den

    def drift(self, x):
        x = np.asarray(x, dtype=float)
        s, c, inv_total, inv_den = self._parts(x)
        w = x[..., 3]
        t = self.m_pole * self.l * w * w * s * inv_total
        wdot = (self.g * s - c * t) * inv_den
        vdot = t - self.m_pole * self.l * wdot * c * inv_total
        return np.stack([x[..., 2], w, vdot, wdot], axis=-1)

    def input_matrix(self, x):
        x = np.asarray(x, dtype=float)
        s, c, inv_total, inv_den = self._parts(x)
        gw = -c * inv_total * inv_den                          # ∂ω̇/∂u
        gv = inv_total - self.m_pole * self.l * gw * c * inv_total   # ∂v̇/∂u
        zero = np.zeros_like(gw)
        return np.stack([zero, zero, gv, gw], axis=-1)[..., None]
