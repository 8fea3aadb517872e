"""What the raw fit predicts, for comparison with the control model built from it.

The control model (eigen-coordinates, shifted to x_eq, possibly truncated, inputs as a continuous bilinear term)
is derived from the least-squares fit.  To show what the derivation costs, the fit itself is rolled out on the
same held-out windows and scored with the same metric as :func:`~kexp.identify.quality.prediction_error`
(‖x̂(t+hΔ) − x(t+hΔ)‖ / ‖x(t+hΔ) − x_eq‖ over all windows):

- unforced data: the plain EDMD step φ ← K φ on the full dictionary (the unconstrained ``raw_K``);
- forced data (inputs regressed): the one-step regression itself, φ(x⁺) = [φ̄, u^α φ̄ …]·coef (``raw_coef``),
  under the recorded inputs.

x̂ is read from the dictionary's first-degree monomials: x = center + scale·φ_lin.
"""
from __future__ import annotations

import numpy as np

from ..data.runs import PairSource, window_samples


def _state(dictionary, phi: np.ndarray) -> np.ndarray:
    x = phi[:, dictionary.linear_indices] * dictionary._scale
    return x if dictionary.center is None else x + np.asarray(dictionary.center)


def raw_fit_error(fit, dictionary, dataset: PairSource, h: int, x_eq: np.ndarray,
                  max_forced_windows: int = 500) -> float:
    """Relative h-step prediction error of the raw fit (``fit.raw_K``, or ``fit.raw_coef`` for a regression fit)
    on ``dataset``'s windows, as prediction_error measures the model's.  NaN without windows; inf if it blows up."""
    forced = dataset.forced and hasattr(fit, "raw_coef")
    x0, truth, U = window_samples(dataset, h, max_forced_windows if forced else 20000, inputs=forced)
    if x0.shape[0] == 0:
        return float("nan")
    with np.errstate(over="ignore", invalid="ignore"):
        phi = dictionary.lift(x0)
        if forced:
            coef, expo = fit.raw_coef, np.array(fit.monomials, dtype=float)
            ones = np.ones((phi.shape[0], fit.n_extra))
            for j in range(h):
                bar = np.hstack([phi, ones])
                umono = np.prod(U[:, j, None, :] ** expo[None], axis=2)        # (w, n_mono)
                reg = np.hstack([bar] + [bar * umono[:, i:i + 1] for i in range(expo.shape[0])])
                phi = reg @ coef
        elif hasattr(fit, "raw_K"):
            kt = fit.raw_K.T
            for _ in range(h):
                phi = phi @ kt
        else:   # a regression fit on unforced windows: its u = 0 block, intercept included
            drift, ones = fit.raw_coef[: fit.n_bar], np.ones((phi.shape[0], fit.n_extra))
            for _ in range(h):
                phi = np.hstack([phi, ones]) @ drift
        xh = _state(dictionary, phi)
    if not np.isfinite(xh).all():
        return float("inf")
    denom = np.linalg.norm(truth - x_eq)
    return float(np.linalg.norm(xh - truth) / denom) if denom > 0 else float("nan")


def versus_fit(fit, dictionary, dataset: PairSource, model_err: dict, x_eq: np.ndarray, dt: float, *,
               dropped: bool, regress: bool) -> tuple[dict, str | None]:
    """({"<h·Δ>_s": {"model": e, "fit": e_fit}}, warning or None): the control model's errors ``model_err``
    ({steps: relative error}) beside the raw fit's on the same windows, and a warning naming the likely cause
    when the model is > 10 % worse than its fit (and by > 1 % of the state's excursion)."""
    out = {f"{h * dt:g}_s": {"model": err, "fit": raw_fit_error(fit, dictionary, dataset, h, x_eq)}
           for h, err in model_err.items()}
    name, worst = max(out.items(), key=lambda kv: kv[1]["model"] - 1.1 * kv[1]["fit"])
    cost = worst["model"] - worst["fit"]
    if not (cost > 0.1 * worst["fit"] and cost > 0.01):
        return out, None
    cause = ("eigen-coordinates were left out (identification.keep / max_residual)" if dropped else
             "the inputs' continuous bilinear term is first order in u (more forced data helps)" if regress else
             "the equilibrium shift drops a drift (identification.fix_equilibrium=true)")
    return out, (f"the control model predicts worse than the fit it comes from: {name.replace('_', ' ')} error "
                 f"{worst['model']:.1%} against the raw fit's {worst['fit']:.1%}; {cause}")
