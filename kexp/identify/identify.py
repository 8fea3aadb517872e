"""identify(): the front door from a Dataset to a KoopmanBilinearModel.

EDMD by streamed least squares → eigenfunctions (left eigenvectors) and continuous eigenvalues → real
canonical transform and block-diagonal Λ → optional selection of well-predicting eigenfunctions →
B_i, b_i by projection of L_{G_i}Ψ → C → held-out prediction errors, all in ``model.report``.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from threadpoolctl import threadpool_limits

from ..data.runs import PairSource, strided_samples
from ..dictionary import Monomials
from ..errors import ConfigError, DataError, require_number, require_seed
from ..systems.base import ControlAffineSystem
from .edmd import METHODS, fit_least_squares
from .eigen import IdentificationWarning, eigenfunctions
from .model import KoopmanBilinearModel
from .noise_check import check_estimator, fit_iv_source, noise_report
from .projection import input_matrices, output_matrix_exact, output_matrix_lstsq
from .regression import fit_bilinear
from .fit_rollout import versus_fit
from .quality import eigenfunction_residuals, prediction_error


INPUT_METHODS = ("projection", "regression")


@dataclass(frozen=True)
class IdentifyConfig:
    """Settings of identification.

    method: 'qr' (streamed TSQR, default) or 'gram' (normal equations).  rcond: relative singular-value cut-off
    of Φ_X.  chunk_size: pairs per streamed chunk.  on_invalid: 'error' | 'drop' for eigenvalues without a
    logarithm.  keep: keep at most this many eigen-coordinates, best residual first (pairs stay together; the
    constant eigenfunction is never a coordinate).  max_residual: drop eigenfunctions whose relative residual
    over ``residual_horizon`` seconds exceeds this.  holdout: fraction of trajectories held out for the quality
    report (and the residual ranking).  prediction_horizon: seconds, for the long prediction error.
    inputs: how B_i, b_i are found — 'projection' (of L_GᵢΨ, needs the system's G; unforced data) or
    'regression' (from forced data, G never evaluated; see regression.py).  input_degree: degree of the input
    monomials in the regression (3: the slope is exact to (Δ‖B‖)³).  compare_projection: with regression, also
    project with the system's G on the same eigen-coordinates and report the relative differences.
    fix_equilibrium: impose K φ(x_eq) = φ(x_eq) in the fit (x_eq is an equilibrium of the unforced system), so
    the model shifted to x_eq drops no drift (fixed_point.py); false: the paper's unconstrained EDMD; None (auto):
    true for a dictionary without a constant (centred there, only a regression's intercept is affected), false
    with a constant (the paper's recipe: on its circle data, which never visit x_eq, the constraint moved a slow
    mode and the default closed loop failed, J 3.98 → 145, measured).
    estimator: 'ls' (least squares) or 'iv' (instrumental variables, for noisy data: kexp.identify.iv) with the
    sample ``iv_lag`` steps earlier as instrument.
    """

    method: str = "qr"
    rcond: float = 1e-13
    chunk_size: int = 20000
    on_invalid: str = "error"
    keep: int | None = None
    max_residual: float | None = None
    residual_horizon: float = 0.1
    holdout: float = 0.2
    holdout_seed: int = 0
    prediction_horizon: float = 1.0
    inputs: str = "projection"
    input_degree: int = 3
    compare_projection: bool = False
    fix_equilibrium: bool | None = None
    estimator: str = "ls"
    iv_lag: int = 1

    def __post_init__(self):
        for key in ("rcond", "residual_horizon", "prediction_horizon", "holdout"):
            require_number(getattr(self, key), f"identification.{key}")
        require_number(self.chunk_size, "identification.chunk_size", integer=True)
        require_seed(self.holdout_seed, "identification.holdout_seed")
        if self.method not in METHODS:
            raise ConfigError(f"identification.method={self.method!r}; valid: {METHODS}")
        if not 0 < self.rcond < 1:
            raise ConfigError(f"identification.rcond={self.rcond}: use a number in (0, 1)")
        if self.chunk_size < 1:
            raise ConfigError(f"identification.chunk_size={self.chunk_size}: use an int >= 1")
        if self.on_invalid not in ("error", "drop"):
            raise ConfigError(f"identification.on_invalid={self.on_invalid!r}; valid: 'error', 'drop'")
        if self.keep is not None:
            require_number(self.keep, "identification.keep", integer=True)
            if self.keep < 1:
                raise ConfigError(f"identification.keep={self.keep}: use an int >= 1 or null (keep all)")
        if self.max_residual is not None:
            require_number(self.max_residual, "identification.max_residual")
            if not self.max_residual > 0:
                raise ConfigError(f"identification.max_residual={self.max_residual}: use a number > 0 or null")
        for key in ("residual_horizon", "prediction_horizon"):
            value = getattr(self, key)
            if not 0 < value < np.inf:
                raise ConfigError(f"identification.{key}={value}: use a finite number of seconds > 0")
        if not isinstance(self.compare_projection, (bool, np.bool_)):
            raise ConfigError(f"identification.compare_projection={self.compare_projection!r}: use true or false")
        if not isinstance(self.fix_equilibrium, (bool, np.bool_, type(None))):
            raise ConfigError(f"identification.fix_equilibrium={self.fix_equilibrium!r}: use true, false or null "
                              "(auto: true for a dictionary without a constant)")
        if not 0 <= self.holdout < 1:
            raise ConfigError(f"identification.holdout={self.holdout}: use a fraction in [0, 1)")
        if self.inputs not in INPUT_METHODS:
            raise ConfigError(f"identification.inputs={self.inputs!r}; valid: {INPUT_METHODS}")
        require_number(self.input_degree, "identification.input_degree", integer=True)
        if not 1 <= self.input_degree <= 5:
            raise ConfigError(f"identification.input_degree={self.input_degree}: use an int in 1..5")
        check_estimator(self.estimator, self.iv_lag)


def _unforced_part(dataset: PairSource) -> PairSource:
    """The trajectories run without input, if a forced dataset has any (eigenfunction residuals measure the
    unforced evolution); else the dataset itself (then the residuals include the input's effect)."""
    if not dataset.forced:
        return dataset
    idle = ~dataset.run_forced()
    return dataset.subset(np.flatnonzero(idle)) if idle.any() else dataset


def auto_scale(dataset: PairSource, center=None) -> tuple[float, ...]:
    """Per-state scale for the dictionary: the largest |x_i − center_i| over kept samples (center None: the
    origin; 1 where that is 0)."""
    st = dataset.stats()
    s = st.absmax if center is None else np.maximum(np.abs(st.high - center), np.abs(st.low - center))
    return tuple(float(v) if v > 0 else 1.0 for v in s)


def _select(eig, residual, cfg: IdentifyConfig) -> np.ndarray:
    blocks = [idx for idx in eig.blocks() if eig.constant not in idx]
    if cfg.max_residual is not None:
        blocks = [idx for idx in blocks if not residual[idx[0]] > cfg.max_residual]
    if cfg.keep is not None:
        blocks.sort(key=lambda idx: (np.nan_to_num(residual[idx[0]], nan=np.inf), idx[0]))
        chosen, count = [], 0
        for idx in blocks:
            if count + idx.size <= cfg.keep:
                chosen.append(idx)
                count += idx.size
        blocks = chosen
    if not blocks:
        raise ConfigError("eigenfunction selection kept nothing; raise identification.keep or max_residual")
    return np.sort(np.concatenate(blocks))


@threadpool_limits.wrap(limits=1)   # one BLAS thread: the model must not depend on the machine's core count
def identify(system: ControlAffineSystem | None, dataset: PairSource, dictionary: Monomials,
             config: IdentifyConfig = IdentifyConfig()) -> KoopmanBilinearModel:
    """Identify the bilinear Koopman model of ``system`` from the unforced ``dataset`` (a Dataset or recorded runs
    streamed from files, :class:`~kexp.data.streaming.RecordedRuns`: any :class:`~kexp.data.runs.PairSource`).

    F is used only through the data.  With ``config.inputs='projection'`` G_i (the input fields) are taken from
    ``system`` for B_i, b_i and the data must be unforced; with 'regression' B_i, b_i are regressed from forced
    data and G is never evaluated (only ``system.n``, ``m``, ``equilibrium`` and names are read).  BLAS runs on
    one thread here, so the model is the same whatever OPENBLAS_NUM_THREADS is (tested).  ``system=None``: a
    system known only from the data (:func:`~kexp.identify.datasystem.system_of_data`: x_eq the origin; m = 0, a
    drift-only model, for unforced data; G is never evaluated, as for any system with m = 0).
    """
    if system is None:   # known only from its data: n, m from the data, G never evaluated (kexp.identify.datasystem)
        from .datasystem import system_of_data
        system = system_of_data(dataset) if hasattr(dataset, "forced") else system
    for value, kind, what in ((system, ControlAffineSystem, "system"), (dictionary, Monomials, "dictionary"),
                              (config, IdentifyConfig, "config")):
        if not isinstance(value, kind):
            raise ConfigError(f"identify(): {what}={value!r:.80}; expected a {kind.__name__}")
    if not (hasattr(dataset, "split") and hasattr(dataset, "iter_pairs")):
        raise ConfigError(f"identify(): dataset={dataset!r:.80}; give a Dataset (kexp.data.collect) or recorded "
                          "runs (kexp.data.open_runs)")
    regress = config.inputs == "regression"
    if regress and not dataset.forced:
        raise DataError("identification.inputs=regression needs forced data: collect under an input excitation "
                        "(data.excitation) or read recorded (t, x, u) runs")
    if regress and dataset.pair_rule != "next":
        raise ConfigError("identification.inputs=regression needs next-sample pairs: set data.pairs=next")
    if not regress and dataset.forced:
        raise DataError("identify() fits the drift from unforced data, but this dataset was collected under an "
                        "excitation input; set data.excitation=null, or identification.inputs=regression to "
                        "regress B and b from the forced data")
    if dictionary.n != system.n or dataset.n != system.n:
        raise ConfigError(f"dimension mismatch: system n={system.n}, dictionary n={dictionary.n}, data n={dataset.n}")
    recorded = getattr(dataset, "system_name", None)
    if recorded not in (None, "", "recorded") and recorded != system.name:   # "recorded": runs read without a name
        raise DataError(f"the dataset was collected with system {recorded!r}, but identify() was given system "
                        f"{system.name!r}; identify with the system that produced the data")
    train, test = dataset.split(config.holdout, config.holdout_seed)
    if train.n_traj == 0:
        raise DataError(f"identification.holdout={config.holdout} holds out all {dataset.n_traj} trajectories, "
                        "leaving none to fit: lower identification.holdout (e.g. 0.2) or collect more trajectories")
    quality_data = test if test is not None else train
    lie = lambda X: dictionary.lie(X, system.input_matrix(X))  # noqa: E731
    x_eq = np.asarray(system.equilibrium, dtype=float)
    fix = config.fix_equilibrium if config.fix_equilibrium is not None else dictionary.constant_index is None
    fixed = dictionary.lift(x_eq)[0] if fix else None
    if config.estimator == "iv":
        fit = fit_iv_source(train, dictionary, config, lie=lie, m=system.m, regress=regress, fixed_point=fixed)
    elif regress:
        fit = fit_bilinear(train.iter_pairs(config.chunk_size, with_inputs=True), dictionary.lift, m=system.m,
                           degree=config.input_degree, method=config.method, rcond=config.rcond,
                           add_constant=dictionary.constant_index is None, fixed_point=fixed)
    else:
        fit = fit_least_squares(train.iter_pairs(config.chunk_size), dictionary.lift, lie_inputs=lie, m=system.m,
                                method=config.method, rcond=config.rcond,
                                add_constant=dictionary.constant_index is None, fixed_point=fixed)
    if fit.n_pairs < 2 * dictionary.size:
        raise DataError(f"{fit.n_pairs} training pairs for {dictionary.size} dictionary functions: collect at least "
                        f"{2 * dictionary.size} (more trajectories or a longer duration) or lower the degree")
    K = fit.K
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", IdentificationWarning)
        eig = eigenfunctions(K, fit.r11, fit.n_pairs, dataset.dt, dataset.pair_rule,
                             constant_index=dictionary.constant_index, on_invalid=config.on_invalid)
    notes = [str(w.message) for w in caught]
    h_res = max(1, int(round(config.residual_horizon / dataset.dt)))
    residual = eigenfunction_residuals(_unforced_part(quality_data), dictionary.lift, eig.T, eig.eigenvalues,
                                       eig.block, h_res)
    keep = _select(eig, residual, config)
    psi0_full = dictionary.lift(x_eq)[0] @ eig.T
    B, b, g_resid = input_matrices(fit, eig.T, keep, eig.constant, psi0_full,
                                   lie_targets=fit.lie_targets(dataset.dt) if regress else None)
    versus_projection = None
    if regress and config.compare_projection:   # a diagnostic where G is known: never used by the model
        pfit = fit_least_squares(train.iter_pairs(config.chunk_size), dictionary.lift, lie_inputs=lie, m=system.m,
                                 method=config.method, rcond=config.rcond,
                                 add_constant=dictionary.constant_index is None, fixed_point=fixed)
        Bp, bp, _ = input_matrices(pfit, eig.T, keep, eig.constant, psi0_full)
        scale = max(float(np.hypot(np.linalg.norm(Bp), np.linalg.norm(bp))), 1e-300)   # B can be 0 (b carries u)
        versus_projection = {"B": float(np.linalg.norm(B - Bp)) / scale, "b": float(np.linalg.norm(b - bp)) / scale}
    all_kept = keep.size + (eig.constant >= 0) == eig.k and eig.k == dictionary.size
    scale = np.ones(system.n) if dictionary.scale is None else np.asarray(dictionary.scale)
    if all_kept:
        C = output_matrix_exact(eig.T, keep, dictionary.linear_indices, scale)
        c_resid = 0.0
    else:
        C, c_resid = output_matrix_lstsq(fit, eig.T, keep, eig.constant, psi0_full, dictionary.linear_indices,
                                         scale, x_eq)
    Lam = eig.Lambda[np.ix_(keep, keep)]
    psi0 = psi0_full[keep]
    drift = Lam @ psi0
    report = {
        "data": dataset.report.lines() if dataset.report else [],
        "pair_rule": dataset.pair_rule,
        "n_pairs_train": fit.n_pairs,
        "n_traj_test": 0 if test is None else test.n_traj,
        "method": fit.method,
        "cond_phi_x": fit.cond,
        "cond_gram": fit.cond ** 2,
        "rank": fit.rank,
        "dictionary_size": dictionary.size,
        "k_fit_residual": fit.relative_residual(0),
        "inputs": config.inputs,
        "fix_equilibrium": bool(fix),
        "estimator": config.estimator,
        "iv_lag": config.iv_lag if config.estimator == "iv" else None,
        "input_projection_residual": g_resid.tolist(),
        "dictionary_lie_residual": None if regress else [fit.relative_residual(1 + i) for i in range(system.m)],
        "input_regression_residual": fit.relative_residual(0) if regress else None,
        "input_degree": config.input_degree if regress else None,
        "input_vs_projection": versus_projection,
        "output_fit_residual": c_resid,
        "constant_eigenfunction": bool(eig.constant >= 0),
        "eigvec_cond": eig.eigvec_cond,
        "drift_at_equilibrium": float(np.linalg.norm(drift)),
        "drift_at_equilibrium_x": float(np.linalg.norm(C @ drift)),
        "residual_horizon_steps": h_res,
        "kept": int(keep.size),
        "dropped": int(eig.k - keep.size - (eig.constant >= 0)),
        "warnings": notes,
    }
    model = KoopmanBilinearModel(
        Lambda=Lam, B=B, b=b, C=C, T=eig.T[:, keep], psi0=psi0, x_eq=x_eq, eigenvalues=eig.eigenvalues[keep],
        discrete=eig.discrete[keep], block=eig.block[keep], residual=residual[keep], drift=drift,
        dictionary=dictionary, dt=dataset.dt, system=system.name, state_names=tuple(system.state_names),
        report=report)
    if versus_projection is not None:   # the input's effect on ẋ as each model sees it, over the training states
        Z = model.lift(strided_samples(train, 5000))
        d = np.stack([(Z @ (B[i] - Bp[i]).T + (b[i] - bp[i])) @ C.T for i in range(system.m)])
        ref = np.stack([(Z @ Bp[i].T + bp[i]) @ C.T for i in range(system.m)])
        versus_projection["field_x"] = float(np.linalg.norm(d) / max(np.linalg.norm(ref), 1e-300))
    report["noise"], noise_notes = noise_report(fit, config, dataset, train, quality_data, dictionary, x_eq,
                                                system.state_names, regress=regress)
    notes.extend(noise_notes)
    h_pred = max(1, int(round(config.prediction_horizon / dataset.dt)))
    model_err = {hh: prediction_error(model, quality_data, hh) for hh in (h_pred, 2 * h_pred)}
    report["prediction_error"] = {"1_step": prediction_error(model, quality_data, 1),
                                  f"{config.prediction_horizon:g}_s": model_err[h_pred]}
    report["prediction_data"] = "held-out" if test is not None else "training"
    report["prediction_vs_fit"], note = versus_fit(fit, dictionary, quality_data, model_err, x_eq, dataset.dt,
                                                   dropped=bool(report["dropped"]), regress=regress)
    notes += [note] if note else []
    far = report["prediction_error"][f"{config.prediction_horizon:g}_s"]
    if not far <= 1.0:   # worse than predicting x_eq, or overflowed: the data did not determine the model
        notes.append(f"the model's {config.prediction_horizon:g} s prediction on the {report['prediction_data']} "
                     f"trajectories is {'unbounded' if not np.isfinite(far) else f'{far:.0%} off'}, worse than "
                     f"predicting x_eq: the data do not determine the dynamics (cond(Φ_X) = {fit.cond:.1e}); "
                     "record more runs from more initial conditions (e.g. without feedback), or lower the degree")
    return model
