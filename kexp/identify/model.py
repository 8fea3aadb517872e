"""The identified bilinear Koopman model

    ż = Λ z + Σ_i u_i (B_i z + b_i),     x ≈ x_eq + C z,     z = Ψ(x) − Ψ(x_eq),  Ψ(x) = φ(x) @ T.

Shapes: Λ (k, k); B (m, k, k); b (m, k); C (n, k); T (N, k); eigenvalues (k,) complex (continuous).
Saved as one ``.npz`` holding arrays plus a JSON ``meta`` string (no pickle), with a format version.
"""
from __future__ import annotations

import json
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.linalg as sla

from ..dictionary import Monomials
from ..errors import ConfigError, ModelFileError, is_number

FORMAT = "kexp-koopman-bilinear"
FORMAT_VERSION = 1
_ARRAYS = ("Lambda", "B", "b", "C", "T", "psi0", "x_eq", "eigenvalues", "discrete", "block", "residual", "drift")


def _ro(a, dtype=float):
    a = np.array(a, dtype=dtype, copy=True)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class KoopmanBilinearModel:
    """A frozen bilinear model in real eigenfunction coordinates (see module docstring).

    ``residual`` (k,): per coordinate, the relative multi-step prediction residual of its eigenfunction
    (NaN where not measured); ``drift`` (k,): Λ·Ψ(x_eq), the model's drift at the equilibrium that the shifted
    model drops (zero for exact eigenfunctions); ``report``: JSON-able facts about the fit.
    """

    Lambda: np.ndarray
    B: np.ndarray
    b: np.ndarray
    C: np.ndarray
    T: np.ndarray
    psi0: np.ndarray
    x_eq: np.ndarray
    eigenvalues: np.ndarray
    discrete: np.ndarray
    block: np.ndarray
    residual: np.ndarray
    drift: np.ndarray
    dictionary: Monomials
    dt: float
    system: str
    state_names: tuple[str, ...]
    report: dict = field(default_factory=dict, compare=False)

    def __post_init__(self):
        for name in _ARRAYS:
            dtype = complex if name in ("eigenvalues", "discrete") else (int if name == "block" else float)
            object.__setattr__(self, name, _ro(getattr(self, name), dtype))
        if self.x_eq.shape != (self.dictionary.n,):
            raise ConfigError(f"inconsistent model: x_eq {self.x_eq.shape} (want ({self.dictionary.n},), the "
                              "dictionary's n)")
        k = self.Lambda.shape[0]
        n = self.x_eq.shape[0]
        checks = [(self.Lambda.shape == (k, k), f"Lambda {self.Lambda.shape}"),
                  (self.B.ndim == 3 and self.B.shape[1:] == (k, k), f"B {self.B.shape} (want (m, {k}, {k}))"),
                  (self.b.shape == (self.B.shape[0], k), f"b {self.b.shape}"),
                  (self.C.shape == (n, k), f"C {self.C.shape} (want ({n}, {k}))"),
                  (self.T.shape == (self.dictionary.size, k), f"T {self.T.shape}"),
                  (self.psi0.shape == (k,), f"psi0 {self.psi0.shape}"),
                  (self.eigenvalues.shape == (k,), f"eigenvalues {self.eigenvalues.shape}")]
        for ok, what in checks:
            if not ok:
                raise ConfigError(f"inconsistent model: {what}")
        for name in ("Lambda", "B", "b", "C", "T", "psi0", "x_eq"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise ConfigError(f"model {name} contains NaN/inf")
        if not isinstance(self.state_names, (tuple, list)) or len(self.state_names) != n:
            raise ConfigError(f"inconsistent model: state_names={self.state_names!r:.80}; want {n} names")
        dt = self.dt
        if not (is_number(dt) and 0 < dt < np.inf):
            raise ConfigError(f"model dt={dt!r}: the sampling time must be a finite number > 0 seconds")

    def __eq__(self, other) -> bool:
        """Exact equality of every array and setting (the report is not compared)."""
        if not isinstance(other, KoopmanBilinearModel):
            return NotImplemented
        return (all(np.array_equal(getattr(self, a), getattr(other, a), equal_nan=True) for a in _ARRAYS)
                and (self.dictionary, self.dt, self.system, self.state_names)
                == (other.dictionary, other.dt, other.system, other.state_names))

    __hash__ = None  # type: ignore[assignment]

    # ------------------------------------------------------------------------------------------------
    @property
    def k(self) -> int:
        return self.Lambda.shape[0]

    @property
    def n(self) -> int:
        return self.x_eq.shape[0]

    @property
    def m(self) -> int:
        return self.B.shape[0]

    def lift(self, x: np.ndarray) -> np.ndarray:
        """z = Ψ(x) − Ψ(x_eq): (M, n) -> (M, k), or (n,) -> (k,)."""
        x = np.asarray(x, dtype=float)
        if x.shape[-1:] != (self.n,):
            raise ConfigError(f"model.lift: x must have shape (n,) or (M, n) with n={self.n}, got {x.shape}")
        z = self.dictionary.lift(x.reshape(-1, self.n)) @ self.T - self.psi0
        return z[0] if x.ndim == 1 else z

    def lift_jacobian(self, x: np.ndarray) -> np.ndarray:
        """∂z/∂x: (M, n) -> (M, k, n)."""
        return np.einsum("Nk,MNn->Mkn", self.T, self.dictionary.jacobian(np.atleast_2d(x)))

    def to_state(self, z: np.ndarray) -> np.ndarray:
        """x̂ = x_eq + C z: (..., k) -> (..., n)."""
        return self.x_eq + np.asarray(z) @ self.C.T

    def step_matrices(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Exact one-step map of the model for input ``u`` (m,) held over Δ: z⁺ = Ad z + cd."""
        try:
            u = np.asarray(u, dtype=float).reshape(self.m)
        except ValueError:   # the error path only: the closed loop calls this for every new input
            raise ConfigError(f"model.step_matrices: u must have shape ({self.m},), got {np.shape(u)}") from None
        A = self.Lambda + np.einsum("i,ijk->jk", u, self.B)
        c = u @ self.b
        aug = np.zeros((self.k + 1, self.k + 1))
        aug[: self.k, : self.k] = A
        aug[: self.k, self.k] = c
        e = sla.expm(aug * self.dt)
        return e[: self.k, : self.k], e[: self.k, self.k]

    def predict(self, x0: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Simulate the model from x0 (n,) under piecewise-constant inputs u (T, m) held for Δ each (exact
        matrix exponential per step).  Returns (x̂ (T+1, n), z (T+1, k))."""
        u = np.asarray(u, dtype=float)
        if u.ndim == 1:
            u = u[:, None]
        if u.ndim != 2 or u.shape[1] != self.m:
            raise ConfigError(f"predict: u must have shape (T, {self.m}), got {u.shape}")
        x0 = np.asarray(x0, dtype=float)
        if x0.shape[-1:] != (self.n,) or x0.size != self.n:
            raise ConfigError(f"predict: x0 must have shape ({self.n},), got {x0.shape}")
        z = np.empty((u.shape[0] + 1, self.k))
        z[0] = self.lift(x0)
        cache: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}
        for t, ut in enumerate(u):
            key = ut.tobytes()
            if key not in cache:
                cache[key] = self.step_matrices(ut)
            ad, cd = cache[key]
            z[t + 1] = ad @ z[t] + cd
        return self.to_state(z), z

    def rhs(self, z: np.ndarray, u: np.ndarray) -> np.ndarray:
        """ż = Λz + Σ u_i (B_i z + b_i) for z (M, k), u (M, m)."""
        z = np.asarray(z, dtype=float)
        u = np.asarray(u, dtype=float)
        return z @ self.Lambda.T + np.einsum("Mi,ijk,Mk->Mj", u, self.B, z) + u @ self.b

    def step_batch(self, z: np.ndarray, u: np.ndarray, substeps: int = 10) -> np.ndarray:
        """One sample-and-hold step of Δ for many states at once (RK4 with ``substeps``; with ‖(Λ+uB)Δ‖ ≤ 0.5
        the relative error is below 1e-9).  z (M, k), u (M, m) -> (M, k)."""
        h = self.dt / substeps
        z = np.array(z, dtype=float)
        for _ in range(substeps):
            k1 = self.rhs(z, u)
            k2 = self.rhs(z + 0.5 * h * k1, u)
            k3 = self.rhs(z + 0.5 * h * k2, u)
            k4 = self.rhs(z + h * k3, u)
            z = z + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return z

    def free_response(self, z0: np.ndarray, steps: int) -> np.ndarray:
        """Unforced model response z(jΔ) = exp(ΛjΔ) z0 for j = 0..steps; z0 (M, k) -> (steps+1, M, k)."""
        if not (is_number(steps, integer=True) and steps >= 0):
            raise ConfigError(f"free_response: steps={steps!r}; use an int >= 0")
        if np.shape(z0)[-1:] != (self.k,):
            raise ConfigError(f"free_response: z0 must have shape (M, {self.k}) or ({self.k},), got {np.shape(z0)}")
        ad = sla.expm(self.Lambda * self.dt)
        out = np.empty((steps + 1,) + np.shape(z0))
        out[0] = z0
        for j in range(steps):
            out[j + 1] = out[j] @ ad.T
        return out

    # ------------------------------------------------------------------------------------------------
    def summary(self) -> str:
        from .summary import model_summary
        return model_summary(self)

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        if path.suffix != ".npz":
            path = path.with_suffix(".npz")
        meta = {"format": FORMAT, "version": FORMAT_VERSION, "dictionary": self.dictionary.spec(), "dt": self.dt,
                "system": self.system, "state_names": list(self.state_names), "report": self.report}
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez(tmp, meta=np.array(json.dumps(meta, sort_keys=True)), **{a: getattr(self, a) for a in _ARRAYS})
        tmp.replace(path)
        return path

    @classmethod
    def load(cls, path: str | Path) -> "KoopmanBilinearModel":
        if not isinstance(path, (str, os.PathLike)):
            raise ConfigError(f"KoopmanBilinearModel.load(path={path!r}): give the model file's path (str or Path)")
        path = Path(path)
        if not path.exists():
            raise ModelFileError(f"model file {path} does not exist; run identification first or fix the path")
        try:
            with np.load(path, allow_pickle=False) as f:
                meta = json.loads(str(f["meta"]))
                arrays = {a: f[a] for a in _ARRAYS}
        except (OSError, ValueError, KeyError, EOFError, NotImplementedError, zipfile.BadZipFile) as exc:  # corrupt
            raise ModelFileError(f"model file {path} is not a readable kexp model ({type(exc).__name__}: {exc}); "
                                 "re-run identification to recreate it") from None
        if not isinstance(meta, dict) or meta.get("format") != FORMAT:
            raise ModelFileError(f"{path} is not a kexp model file "
                                 f"(format {meta.get('format') if isinstance(meta, dict) else None!r})")
        if meta.get("version") != FORMAT_VERSION:
            raise ModelFileError(f"{path} has model format version {meta.get('version')}; this kexp reads version "
                                 f"{FORMAT_VERSION}: re-run identification to recreate it")
        try:
            dt = meta["dt"]
            if not is_number(dt):
                raise ConfigError(f"dt={dt!r} is not a number")
            if not (isinstance(meta["system"], str) and isinstance(meta["report"], dict)):
                raise ConfigError("system must be a string and report a mapping")
            return cls(**arrays, dictionary=Monomials.from_spec(meta["dictionary"]), dt=float(dt),
                       system=meta["system"], state_names=tuple(meta["state_names"]), report=meta["report"])
        except (ConfigError, KeyError, TypeError, ValueError, AttributeError) as exc:   # damaged or hand-edited
            detail = f"missing {exc}" if isinstance(exc, KeyError) else str(exc).splitlines()[0] if str(exc) else ""
            raise ModelFileError(f"model file {path} is damaged ({type(exc).__name__}: {detail}); "
                                 "re-run identification to recreate it") from None
