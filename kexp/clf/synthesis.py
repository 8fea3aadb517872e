"""CLF synthesis by the paper's SDP (eq. 40) and the certificate check.

    min_{σ ≥ 0, P = Pᵀ}  σ − γ·trace(P Σ_i B_i)   s.t.  σI − (PΛ + ΛᵀP) ⪰ 0,   c_L I ⪯ P ⪯ c_U I.

The problem is homogeneous in P: the optimum sits on the bounds, which act as a gain (design pitfall 6).
Nothing here assumes the result is a CLF: :func:`check_certificate` tests it and the report is part of the
result.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from threadpoolctl import threadpool_limits

from ..errors import ClfError, ConfigError, require_number
from .certificate import LONG_K, CertificateReport, check_certificate, check_region, check_region_config
from .lyapunov import QuadraticLyapunov
from .riccati import model_lqr

SOLVERS = ("CLARABEL", "SCS")
# SCS is a first-order solver: at its defaults (1e-4) the default Van der Pol model's P left c_lower by 0.4 %, past
# the 1e-6·c_upper the result is checked to; at 1e-8 it meets the bounds to 1e-8 and costs ~50 ms (k = 21)
SOLVER_OPTIONS = {"CLARABEL": {}, "SCS": {"eps_abs": 1e-8, "eps_rel": 1e-8, "max_iters": 100_000}}
METHODS = ("sdp", "lqr_x")


@dataclass(frozen=True)
class ClfConfig:
    """gamma (γ ≥ 0), c_lower/c_upper (0 < c_L < c_U) as in eq. 40; solver 'CLARABEL' (default) or 'SCS';
    accept_inaccurate: use an 'optimal_inaccurate' P (with a warning in the report) instead of failing.
    region_low/region_high: the box of x (relative to x_eq) where the certificate is sampled, grid points per
    axis ``grid``; rhat_floor: r̂ is at least this fraction of r."""

    gamma: float = 2.0
    c_lower: float = 0.01
    c_upper: float = 1.0
    solver: str = "CLARABEL"
    accept_inaccurate: bool = False
    region_low: float | tuple[float, ...] = -1.0
    region_high: float | tuple[float, ...] = 1.0
    grid: int = 41
    rhat_floor: float = 0.05
    method: str = "sdp"
    q_x: float = 1.0
    r_u: float = 1.0
    eps: float = 1e-4

    def __post_init__(self):
        for key in ("gamma", "c_lower", "c_upper", "q_x", "r_u", "eps", "rhat_floor"):
            require_number(getattr(self, key), f"clf.{key}")
        require_number(self.grid, "clf.grid", integer=True)
        if self.method not in METHODS:
            raise ConfigError(f"clf.method={self.method!r}; valid: {METHODS}")
        if not (self.q_x > 0 and self.r_u > 0 and self.eps > 0):
            raise ConfigError(f"clf.q_x={self.q_x}, clf.r_u={self.r_u}, clf.eps={self.eps}: all must be > 0")
        for key in ("q_x", "r_u"):
            if not np.isfinite(getattr(self, key)):
                raise ConfigError(f"clf.{key}={getattr(self, key)}: use a finite weight > 0 (default 1.0)")
        if not self.eps <= 1:
            raise ConfigError(f"clf.eps={self.eps}: use a small fraction in (0, 1] (default 1e-4): V adds "
                              "eps·λ_max(P_x)·|z|² on the directions C does not see")
        if not isinstance(self.accept_inaccurate, (bool, np.bool_)):
            raise ConfigError(f"clf.accept_inaccurate={self.accept_inaccurate!r}: use true or false")
        check_region_config(self.region_low, self.region_high)
        if not (np.isfinite(self.gamma) and self.gamma >= 0):
            raise ConfigError(f"clf.gamma={self.gamma}: use a finite number >= 0")
        if not (0 < self.c_lower < self.c_upper < np.inf):
            raise ConfigError(f"clf.c_lower={self.c_lower}, clf.c_upper={self.c_upper}: need 0 < c_lower < c_upper")
        if self.solver not in SOLVERS:
            raise ConfigError(f"clf.solver={self.solver!r}; valid: {SOLVERS}")
        if self.grid < 3:
            raise ConfigError(f"clf.grid={self.grid}: use an int >= 3")
        if not 0 < self.rhat_floor <= 1:
            raise ConfigError(f"clf.rhat_floor={self.rhat_floor}: use a fraction in (0, 1]")


@dataclass(frozen=True, eq=False)
class Clf:
    """V(z) = zᵀPz with its SDP status and certificate report.  ``r``, ``r_hat`` are sampled estimates of the
    level sets Ω_r (h decreases V) and Ω_r̂ (sample-and-hold safe set) of the paper."""

    P: np.ndarray
    lyap: QuadraticLyapunov
    status: str
    solver: str
    objective: float
    sigma: float
    certificate: CertificateReport
    config: ClfConfig = field(repr=False)

    @property
    def r(self) -> float:
        return self.certificate.r

    @property
    def r_hat(self) -> float:
        return self.certificate.r_hat

    def summary(self) -> str:
        eig = np.linalg.eigvalsh(self.P)
        how = f"SDP eq. 40, {self.solver}" if self.config.method == "sdp" else "Riccati of the model linearisation (lqr_x)"
        return "\n".join([f"CLF ({how}): status {self.status}, objective {self.objective:.4g}, "
                          f"σ = {self.sigma:.4g}, eig(P) in [{eig[0]:.4g}, {eig[-1]:.4g}]"]
                         + self.certificate.lines())


def solve_sdp(model, config: ClfConfig) -> tuple[np.ndarray, str, float, float]:
    """The paper's SDP (eq. 40) for P (k, k): minimise σ − γ·tr(P ΣB_i) subject to PΛ + ΛᵀP ⪯ σI and
    c_lower·I ⪯ P ⪯ c_upper·I, with ``config.solver``.  Returns (P symmetric (k, k), solver status, objective, σ).
    Raises :class:`~kexp.clf.ClfError` when the solver fails, the status is not optimal (optimal_inaccurate only
    with ``config.accept_inaccurate``) or P's eigenvalues leave [c_lower, c_upper]."""
    import cvxpy as cp
    k = model.k
    P = cp.Variable((k, k), symmetric=True)
    sigma = cp.Variable(nonneg=True)
    eye = np.eye(k)
    lam = model.Lambda
    bsum = model.B.sum(axis=0)
    lyap_expr = P @ lam + lam.T @ P
    cons = [sigma * eye - 0.5 * (lyap_expr + lyap_expr.T) >> 0, P >> config.c_lower * eye, config.c_upper * eye >> P]
    prob = cp.Problem(cp.Minimize(sigma - config.gamma * cp.trace(P @ bsum)), cons)
    try:
        prob.solve(solver=config.solver, **SOLVER_OPTIONS[config.solver])
    except cp.error.SolverError as exc:
        other = "SCS" if config.solver == "CLARABEL" else "CLARABEL"
        raise ClfError(f"CLF SDP: solver {config.solver} failed ({exc}); try clf.solver={other}, or a smaller "
                       f"clf.gamma={config.gamma:g} / clf.c_upper={config.c_upper:g} (they scale the problem)") from None
    status = prob.status
    if status not in ("optimal", "optimal_inaccurate") or P.value is None:
        raise ClfError(f"CLF SDP status {status} with clf.c_lower={config.c_lower:g}, clf.c_upper={config.c_upper:g} "
                       f"(ratio {config.c_upper / config.c_lower:.3g}), clf.gamma={config.gamma:g}: bounds this large "
                       "or this far apart defeat the solver (the defaults 0.01, 1 and 2 solve; keep c_upper/c_lower "
                       "<= 1e8); else check the model (finite Λ, B)")
    if status == "optimal_inaccurate" and not config.accept_inaccurate:
        raise ClfError("CLF SDP solved inaccurately; set clf.solver=CLARABEL, rescale the model, or accept with "
                       "clf.accept_inaccurate=true")
    Pv = 0.5 * (P.value + P.value.T)
    check_bounds(Pv, config)
    return Pv, status, float(prob.value), float(sigma.value)


def check_bounds(P: np.ndarray, config: ClfConfig) -> None:
    """Raise :class:`~kexp.clf.ClfError` when the eigenvalues of the symmetric ``P`` leave [c_lower, c_upper] by
    more than 1e-6·c_upper (what an SDP solver reporting 'optimal' must meet), naming what to change."""
    eig = np.linalg.eigvalsh(P)
    tol = 1e-6 * config.c_upper
    if eig[0] <= 0:
        raise ClfError(f"CLF SDP returned P with smallest eigenvalue {eig[0]:.3g} <= 0: clf.c_lower={config.c_lower:g} "
                       f"is below the solver's accuracy ({tol:.1g} = 1e-6·clf.c_upper); raise clf.c_lower (keep "
                       "c_upper/c_lower <= 1e8)")
    if eig[0] < config.c_lower - tol or eig[-1] > config.c_upper + tol:
        raise ClfError(f"CLF SDP returned P with eigenvalues in [{eig[0]:.6g}, {eig[-1]:.6g}], outside "
                       f"[c_lower, c_upper] = [{config.c_lower}, {config.c_upper}] by more than {tol:.1g}: the "
                       f"solve is unreliable; use clf.solver=CLARABEL (interior point, accurate), rescale the model "
                       f"or the bounds, or use clf.method=lqr_x")


def solve_lqr_x(model, config: ClfConfig) -> tuple[np.ndarray, str, float, float]:
    """V from the model's own linearisation at the equilibrium, in x: with z ≈ J(x − x_eq) (J = ∂z/∂x at x_eq)
    and x − x_eq ≈ Cz, ẋ ≈ CΛJ·x + Cb·u.  P_x solves the Riccati equation of (CΛJ, Cbᵀ, q_x I, r_u I) and
    V(z) = zᵀ(CᵀP_xC + ε·λ_max I)z ≈ xᵀP_x x near x_eq (ε keeps P positive definite on the directions C does not
    see).  Uses only the identified model (F stays unknown)."""
    try:
        Px = model_lqr(model, config.q_x, config.r_u).P
    except ClfError as exc:
        raise ClfError(f"clf.method=lqr_x: {exc}") from None
    Pz = model.C.T @ Px @ model.C
    Pz = 0.5 * (Pz + Pz.T) + config.eps * np.linalg.eigvalsh(Px)[-1] * np.eye(model.k)
    if not np.all(np.isfinite(Pz)):
        raise ClfError(f"clf.method=lqr_x: P is not finite with clf.q_x={config.q_x:g}, clf.r_u={config.r_u:g}, "
                       f"clf.eps={config.eps:g}: use moderate weights (default 1, 1, 1e-4)")
    return Pz, "riccati", float(np.trace(Px)), float("nan")


@threadpool_limits.wrap(limits=1)   # one BLAS thread: P must not depend on the machine's core count
def synthesize_clf(model, config: ClfConfig = ClfConfig(), *, law: str = "sontag", u_min=-5.0, u_max=5.0,
                   law_params: dict | None = None, progress=None) -> Clf:
    """Solve the SDP (or the Riccati equation, ``method='lqr_x'``), then check the certificate of V = zᵀPz for
    the explicit law ``law`` with bounds.  Raises :class:`~kexp.errors.ConfigError` first (before solving) for a
    ``config`` that is not a ClfConfig, a region that does not fit the model's n or a grid over the memory budget
    (:func:`~kexp.clf.certificate.check_region`) or an SDP over the memory budget (:func:`check_sdp_budget`), and
    :class:`~kexp.errors.ClfError` when the solve fails.  ``progress`` (a callable taking one line, e.g. the kexp
    command's echo, or None) is told when a stage starts that takes long: the SDP and the certificate of a model
    with k ≥ :data:`~kexp.clf.certificate.LONG_K`."""
    _check_inputs(model, config)
    check_sdp_budget(config, model.k)
    if progress is not None and config.method == "sdp" and model.k >= LONG_K:
        progress(sdp_announcement(model.k, config.solver))
    P, status, obj, sigma = (solve_sdp if config.method == "sdp" else solve_lqr_x)(model, config)
    return clf_from_P(model, P, config, law=law, u_min=u_min, u_max=u_max, law_params=law_params,
                      status=status, objective=obj, sigma=sigma, progress=progress)


SDP_BYTES_PER_ENTRY = 200   # CLARABEL's peak memory per (k(k+1)/2)² (measured: 1.15 GB at k = 69, ≥ 12.3 GB at 125)


def sdp_bytes(k: int) -> int:
    """An estimate of the memory CLARABEL holds for the SDP of eq. 40 on k eigen-coordinates: its KKT system is
    dense in the k(k+1)/2 entries of each LMI, 200 bytes per (k(k+1)/2)² (peak RSS above the interpreter's, one
    BLAS thread: 0.06 GB at k = 34, 1.15 GB at k = 69, 12.3 GB and growing when stopped after 7 min at k = 125)."""
    return int(SDP_BYTES_PER_ENTRY * (k * (k + 1) // 2) ** 2)


def check_sdp_budget(config: ClfConfig, k: int) -> None:
    """Refuse, before anything long runs, an SDP (``clf.method=sdp``) on ``k`` eigen-coordinates whose estimated
    memory (:func:`sdp_bytes`) exceeds the budget (``$KEXP_MEMORY_BUDGET_GB``, 4 GB by default): ConfigError
    naming clf.method and what to change.  The default budget admits k ≤ 94."""
    from ..control.memory import memory_budget
    if config.method != "sdp":
        return
    need, budget = sdp_bytes(k), memory_budget()
    if need > budget:
        raise ConfigError(f"clf.method=sdp on k={k} eigen-coordinates needs about {need / 1e9:.3g} GB for the SDP "
                          f"(its KKT system is dense in k(k+1)/2 = {k * (k + 1) // 2} unknowns; measured 2 min and "
                          f"1.3 GB at k=69), over the budget of {memory_budget() / 1e9:.3g} GB "
                          "(KEXP_MEMORY_BUDGET_GB): use clf.method=lqr_x (the model's Riccati equation, "
                          "milliseconds) or a lower dictionary.degree")


def sdp_announcement(k: int, solver: str) -> str:
    """The line printed before the SDP of a large model: its size and what it costs (with an interior point its
    time grows about as k⁵: 1.8 s at k = 34 and 2 min at k = 69 measured on this project's loaded 2-core
    machine)."""
    return (f"CLF: SDP (eq. 40) on {k} eigen-coordinates ({k * (k + 1) // 2} unknowns, three {k}×{k} LMIs, "
            f"{solver}, about {sdp_bytes(k) / 1e9:.2g} GB)… its time grows about as k⁵ (2 min at k = 69); "
            "clf.method=lqr_x takes milliseconds")


def clf_from_P(model, P, config: ClfConfig = ClfConfig(), *, law="sontag", u_min=-5.0, u_max=5.0,
               law_params=None, status="given", objective=float("nan"), sigma=float("nan"), progress=None) -> Clf:
    """Wrap a given P (e.g. from another synthesis) with its certificate report.  Raises
    :class:`~kexp.errors.ConfigError` for a P that is not a finite symmetric positive definite (k, k) matrix (and
    as :func:`synthesize_clf` for the model, config, law and bounds).  ``progress``: as for synthesize_clf."""
    from ..control.laws import make_law
    _check_inputs(model, config)
    lyap = QuadraticLyapunov.from_model(model, P)
    h = make_law(law, lyap, u_min, u_max, model=model, weights=(config.q_x, config.r_u), **(law_params or {}))
    report = check_certificate(model, lyap, h, config, progress=progress)
    return Clf(P=lyap.P, lyap=lyap, status=status, solver=config.solver, objective=objective, sigma=sigma,
               certificate=report, config=config)


def _check_inputs(model, config) -> None:
    """The model and config of a synthesis: an identified model (k, n, m, Λ, B, b, C), a ClfConfig whose region
    fits the model (:func:`~kexp.clf.certificate.check_region`)."""
    if not isinstance(config, ClfConfig):
        raise ConfigError(f"config={config!r}: pass a ClfConfig")
    if not all(hasattr(model, a) for a in ("k", "n", "m", "Lambda", "B", "b", "C", "lift")):
        raise ConfigError(f"model={type(model).__name__}: pass the identified model (kexp.identify.identify or "
                          "KoopmanBilinearModel.load)")
    check_region(model, config)


def save_clf(clf: Clf, path) -> None:
    """P, the SDP facts and the certificate report as one .npz (no pickle) at ``path``, its parent folders created;
    the model is not stored."""
    import json
    from pathlib import Path
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, P=clf.P, meta=np.array(json.dumps({
        "status": clf.status, "solver": clf.solver, "objective": clf.objective, "sigma": clf.sigma,
        "certificate": clf.certificate.to_dict()}, default=float)))


def load_clf(path, model, config: ClfConfig) -> Clf:
    """Read a CLF written by :func:`save_clf` (an .npz without pickle) for ``model`` (the model it was synthesised
    for: its Λ, B, b give the Lie derivatives; P must be (k, k)) and attach ``config`` (the ClfConfig it was
    synthesised with).  Returns a :class:`Clf` with the stored status, solver facts and certificate report (not
    re-checked).  Raises :class:`~kexp.errors.ConfigError` naming the file for a missing file or one that save_clf
    did not write, a ``config`` that is not a ClfConfig, or a P that does not fit the model."""
    import json
    import zipfile
    if not isinstance(config, ClfConfig):
        raise ConfigError(f"load_clf: config={config!r}: pass the ClfConfig the CLF was synthesised with")
    try:
        with np.load(path, allow_pickle=False) as f:
            P = f["P"]
            meta = json.loads(str(f["meta"]))
        cert = dict(meta["certificate"])
        cert.pop("verdict", None)
        if "bounds_state" not in cert:   # a file from before the bound was part of the certificate
            cert.update(_bound_fields(model, P, config))
        for key in ("global_mu", "flat_direction", "flat_direction_local"):
            cert[key] = tuple(cert[key])
        report = CertificateReport(**cert)
        facts = {key: meta[key] for key in ("status", "solver", "objective", "sigma")}
    except FileNotFoundError:
        raise ConfigError(f"load_clf: {str(path)!r} does not exist: give the .npz save_clf wrote, or synthesise the "
                          "CLF (synthesize_clf)") from None
    except (OSError, KeyError, ValueError, TypeError, zipfile.BadZipFile) as exc:
        raise ConfigError(f"load_clf: {str(path)!r} is not a CLF file written by save_clf ({type(exc).__name__}: "
                          f"{str(exc).splitlines()[0] if str(exc) else ''}); give the .npz save_clf wrote, or "
                          "synthesise the CLF again") from None
    return Clf(P=P, lyap=QuadraticLyapunov.from_model(model, P), certificate=report, config=config, **facts)


def _bound_fields(model, P, config: ClfConfig) -> dict:
    """The certificate's fields of :func:`~kexp.clf.bound.state_bound` for V = zᵀPz on the region's samples
    (as check_certificate computes them), for a CLF file written before they existed."""
    from .bound import state_bound
    from .certificate import sampled_states
    lyap = QuadraticLyapunov.from_model(model, P)
    x = sampled_states(model, config)[0]
    b = state_bound(model, lyap, x, lyap.value(model.lift(x)), config.region_low, config.region_high)
    return {"c_x": b.c, "flat_direction": b.direction, "c_local": b.c_local,
            "flat_direction_local": b.direction_local, "bound_gain": b.gain, "bounds_state": b.holds}
