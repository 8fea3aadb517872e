"""Control-affine systems  ẋ = F(x) + Σ_i G_i(x) u_i.

Arrays are time-first / batch-first: a state batch has shape ``(..., n)``, an input batch ``(..., m)``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..errors import SystemDefinitionError


@dataclass(frozen=True)
class ControlAffineSystem:
    """Base class of a control-affine system.

    Subclasses implement :meth:`drift` (F) and :meth:`input_matrix` (G); both are vectorised over leading
    batch axes.  ``equilibrium`` is a state with F(x_eq) = 0 (checked by :func:`check_system`),
    ``state_names`` names the n states, ``angle_period`` gives, per state, the period with which it wraps
    (``None`` for a state that does not wrap).  ``constant_input_matrix = True`` declares that G does not depend
    on x (checked by :func:`check_system`); the closed loop then forms G·u once per held input instead of in every
    right-hand-side call of the integrator (the same numbers, about 4× fewer microseconds per call).
    """

    name: ClassVar[str] = "system"
    n: ClassVar[int] = 0
    m: ClassVar[int] = 1
    constant_input_matrix: ClassVar[bool] = False

    # --- to implement -------------------------------------------------------------------------------
    def drift(self, x: np.ndarray) -> np.ndarray:  # (..., n) -> (..., n)
        raise NotImplementedError

    def input_matrix(self, x: np.ndarray) -> np.ndarray:  # (..., n) -> (..., n, m)
        raise NotImplementedError

    @property
    def equilibrium(self) -> np.ndarray:
        return np.zeros(self.n)

    @property
    def state_names(self) -> tuple[str, ...]:
        return tuple(f"x{i + 1}" for i in range(self.n))

    @property
    def angle_period(self) -> tuple[float | None, ...]:
        return (None,) * self.n

    # --- provided -----------------------------------------------------------------------------------
    def rhs(self, x: np.ndarray, u: np.ndarray | None = None) -> np.ndarray:
        """ẋ for states ``x`` (..., n) and inputs ``u`` (..., m) or None (unforced)."""
        f = self.drift(x)
        if u is None:
            return f
        return f + self.input_term(x, u)

    def input_term(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """G(x)·u for states ``x`` (..., n) and inputs ``u`` (..., m): (..., n)."""
        return np.einsum("...ij,...j->...i", self.input_matrix(x), np.asarray(u, dtype=float))

    def wrap(self, x: np.ndarray) -> np.ndarray:
        """Map angle states into [-period/2, period/2); other states unchanged."""
        x = np.array(x, dtype=float, copy=True)
        for i, p in enumerate(self.angle_period):
            if p is not None:
                x[..., i] = (x[..., i] + p / 2) % p - p / 2
        return x

    def describe(self) -> str:
        return f"{self.name} (n={self.n}, m={self.m})"


@dataclass(frozen=True)
class FormulaFreeSystem(ControlAffineSystem):
    """A system known without a formula (a plant kexp does not simulate, recorded runs): what identification, the
    CLF and the LMPC read — n, m, ``equilibrium`` from the field ``x_eq``, ``state_names`` from ``names`` — while
    :meth:`drift` and :meth:`input_matrix` raise the subclass's one-line error (:meth:`_no_formula`), so a stage that
    needs F or G says so instead of computing with a stub.  Subclasses declare the fields and validate them."""

    @property
    def equilibrium(self) -> np.ndarray:
        return np.asarray(self.x_eq, dtype=float)

    @property
    def state_names(self) -> tuple[str, ...]:
        return self.names

    def _no_formula(self, what: str):
        raise NotImplementedError

    def drift(self, x):
        self._no_formula("F")

    def input_matrix(self, x):
        self._no_formula("G")


def check_system(system: ControlAffineSystem, *, n_probe: int = 8, seed: int = 0) -> None:
    """Evaluate F and G on a few probe states and raise a clear error for wrong shapes or non-finite output."""
    n, m = system.n, system.m
    if not (isinstance(n, int) and n >= 1):
        raise SystemDefinitionError(f"system {system.name!r}: n={n!r}; set n to the state dimension (an int >= 1)")
    if not (isinstance(m, int) and m >= 1):
        raise SystemDefinitionError(f"system {system.name!r}: m={m!r}; set m to the input dimension (an int >= 1)")
    xe = np.asarray(system.equilibrium, dtype=float)
    if xe.shape != (n,) or not np.all(np.isfinite(xe)):
        raise SystemDefinitionError(f"system {system.name!r}: equilibrium {xe!r} must be a finite vector of shape ({n},)")
    names = system.state_names
    if len(names) != n:
        raise SystemDefinitionError(f"system {system.name!r}: state_names has {len(names)} entries; it needs n={n}")
    if len(system.angle_period) != n:
        raise SystemDefinitionError(f"system {system.name!r}: angle_period has {len(system.angle_period)} entries; it needs n={n}")
    rng = np.random.default_rng(seed)
    probe = xe + rng.uniform(-1.0, 1.0, (n_probe, n))
    def call(method: str, x):
        try:
            return np.asarray(getattr(system, method)(x))
        except Exception as exc:  # noqa: BLE001 - the user's code: say which call failed, in one line
            detail = str(exc).splitlines()[0] if str(exc) else ""
            raise SystemDefinitionError(f"system {system.name!r}: {method}(x) raised {type(exc).__name__}: {detail} "
                                        f"(check its parameters: {system!r})"[:500]) from None

    f = call("drift", probe)
    if f.shape != (n_probe, n):
        raise SystemDefinitionError(f"system {system.name!r}: drift(x) returned shape {f.shape} for x of shape "
                           f"{probe.shape}; it must return ({n_probe}, {n}) (vectorise over leading axes)")
    g = call("input_matrix", probe)
    if g.shape != (n_probe, n, m):
        raise SystemDefinitionError(f"system {system.name!r}: input_matrix(x) returned shape {g.shape} for x of shape "
                           f"{probe.shape}; it must return ({n_probe}, {n}, {m})")
    if not (np.all(np.isfinite(f)) and np.all(np.isfinite(g))):
        raise SystemDefinitionError(f"system {system.name!r}: drift or input_matrix returned NaN/inf near the equilibrium")
    if system.constant_input_matrix and not np.array_equal(g, np.broadcast_to(g[:1], g.shape)):
        raise SystemDefinitionError(f"system {system.name!r}: constant_input_matrix is True but input_matrix(x) "
                                    "differs between states; set constant_input_matrix = False")
    f0 = np.asarray(system.drift(xe[None]))[0]
    if np.linalg.norm(f0) > 1e-9 * max(1.0, np.linalg.norm(xe)):
        raise SystemDefinitionError(f"system {system.name!r}: F(equilibrium) = {f0}, not 0; "
                           "set `equilibrium` to a state where the drift vanishes")
