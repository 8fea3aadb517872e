"""Diff policies: what a comparison of two run logs asserts, channel by channel and field by field.

``exact``     every number equal (or within ``atol + rtol·|b|`` entry by entry when tolerances are given): the
              same machine, BLAS build and code must reproduce a log bit for bit.
``portable``  what holds on any machine (another CPU, BLAS kernel or thread count).  Discrete fields (status,
              region, active constraint, binds, iteration counts, config) stay exact; numbers are compared
              *norm-wise*: a field's largest difference against ``atol + rtol·(its largest magnitude over the
              channel)``, because perturbation bounds of least squares, eigen-decompositions and a contracting
              closed loop bound norms, not single entries (a small entry of an ill-conditioned mode can move by
              1e-6 of itself while the matrix moves by 1e-9 of its norm).  Quantities that depend on the choice of
              eigen-coordinates (Λ, B, b, C, P, z) are not compared entry by entry; the model is compared by what
              it does: its eigenvalues as a set and its prediction of x from the run's x0 under the run's inputs.

The tolerances of ``portable`` and why (README, "Golden recordings"): the model is a least-squares solution, so
its relative error is bounded by κ·ε + κ²·ε·ρ (κ = cond(Φ_X), ρ = relative residual; Golub & Van Loan §5.3.8).
The paper pendulum is the worst shipped case: κ = 1.5e6, one-step residual ρ ≈ 1e-3, so 3e-10 + 5e-7 ≈ 5e-7 →
``MODEL`` allows 1e-6 of the norm.  Measured across OpenBLAS kernels and thread counts: ≤ 2e-8 (benchmarks/
golden_variation.py).  The certificate's diagnostics include ratios of near-zero quantities (where L_BV ≈ 0):
1e-5.  The open loop integrates the true system and touches no identified quantity: 1e-10.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Mapping

from ..errors import ConfigError


@dataclass(frozen=True)
class Tol:
    """Numbers a, b agree when |a − b| ≤ atol + rtol·scale (scale: |b|, or the field's norm, by policy)."""
    rtol: float = 0.0
    atol: float = 0.0

    def __post_init__(self):
        if not (0 <= self.rtol < float("inf") and 0 <= self.atol < float("inf")):   # inf·0 = nan: no verdict
            raise ConfigError(f"tolerances must be finite and >= 0, got rtol={self.rtol}, atol={self.atol}")

    def bound(self, scale: float) -> float:
        return self.atol + self.rtol * scale


@dataclass(frozen=True)
class ChannelRule:
    """How one channel is compared: ``default`` for numbers not named in ``fields``; ``fields`` maps a field path
    without indices (``"B"``, ``"report.cond_phi_x"``, a prefix like ``"certificate"``) to a tolerance, or to
    None for "not compared"; ``derived`` names checks computed from the whole message (see behaviour.py)."""
    default: Tol
    fields: Mapping[str, Tol | None] = field(default_factory=dict)
    derived: tuple[str, ...] = ()

    def __post_init__(self):
        object.__setattr__(self, "fields", MappingProxyType(dict(self.fields)))

    def tol_for(self, path: str) -> Tol | None:
        """The rule of the longest named prefix of ``path`` (dotted, indices stripped), else ``default``."""
        parts = path.split(".")
        for i in range(len(parts), 0, -1):
            key = ".".join(parts[:i])
            if key in self.fields:
                return self.fields[key]
        return self.default


@dataclass(frozen=True)
class Policy:
    """A named set of channel rules.  ``normwise``: numbers are compared against the field's norm over the
    channel (portable) instead of entry by entry (exact)."""
    name: str
    normwise: bool
    channels: Mapping[str, ChannelRule]
    fallback: ChannelRule

    def __post_init__(self):
        object.__setattr__(self, "channels", MappingProxyType(dict(self.channels)))

    def rule(self, channel: str) -> ChannelRule:
        return self.channels.get(channel, self.fallback)


MODEL = Tol(rtol=1e-6, atol=1e-9)          # anything computed from the identified model
CERTIFICATE = Tol(rtol=1e-5, atol=1e-7)    # certificate diagnostics: ratios of near-zero quantities
TRUE_SYSTEM = Tol(rtol=1e-10, atol=1e-12)  # the true system integrated alone (no identified quantity)
EXACT = Tol()
COORDINATES = ("Lambda", "B", "b", "C")    # entries depend on the eigen-coordinates' scaling, order, rotation

PORTABLE = Policy("portable", True, {
    "/config": ChannelRule(EXACT),
    "/model": ChannelRule(MODEL, {**{c: None for c in COORDINATES}, "eigenvalues_re": None, "eigenvalues_im": None,
                                  "dt": EXACT, "x_eq": EXACT},
                          derived=("eigenvalues", "prediction")),
    "/clf": ChannelRule(MODEL, {"P": None, "certificate": CERTIFICATE}),
    "/step": ChannelRule(MODEL, {"z": None, "k": EXACT, "t": EXACT}),
    "/prediction": ChannelRule(MODEL, {"k": EXACT, "t": EXACT, "t_pred": EXACT}),
    "/open_loop": ChannelRule(TRUE_SYSTEM, {"t": EXACT}),
    "/summary": ChannelRule(MODEL),
}, fallback=ChannelRule(MODEL))

POLICIES = ("exact", "portable")


def make_policy(name: str = "exact", *, rtol: float = 0.0, atol: float = 0.0) -> Policy:
    """``exact`` with optional entry-wise tolerances, or ``portable`` (its own tolerances; rtol/atol must be 0)."""
    if name == "exact":
        return Policy("exact", False, {}, fallback=ChannelRule(Tol(rtol, atol)))
    if name == "portable":
        if rtol or atol:
            raise ConfigError("the portable policy has its own tolerances per channel; drop --rtol/--atol")
        return PORTABLE
    raise ConfigError(f"unknown diff policy {name!r}; valid: {', '.join(POLICIES)}")
