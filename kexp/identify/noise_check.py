"""The estimator choice and the noise report of identify(): the IV fit from a pair source, and the diagnostics and
warnings that go into ``model.report`` (``noise``, ``warnings``) and the printed summary.

- ``identification.estimator=iv``: :func:`fit_iv_source` (lagged instruments, kexp.identify.iv).
- Always: the third-difference noise estimate relative to the data's RMS, the one-step residuals' lag-1
  correlation, the linearisation at x_eq (and for IV the instruments' smallest canonical correlation and the
  least-squares linearisation on the same pairs, free from the same pass).
- ``estimator=ls`` on data whose noise estimate exceeds :data:`~kexp.identify.diagnostics.NOISE_WARN`: a warning
  suggesting IV, and an IV fit on the same data as a reference; a second warning if the fit's linearisation at
  x_eq has lost or gained a complex pair against it.
"""
from __future__ import annotations

import re
from dataclasses import replace

import numpy as np

from ..data.runs import PairSource, pair_chunks
from ..errors import ConfigError, DataError, require_number
from .diagnostics import (NOISE_WARN, REFERENCE_MIN, WEAK_INSTRUMENT, complex_pairs, difference_noise, fmt_eigs, linearisation,
                          residual_lag1)
from .iv import ESTIMATORS, fit_bilinear_iv, fit_iv


def check_estimator(estimator, iv_lag) -> None:
    """One-line ConfigErrors for identification.estimator and identification.iv_lag."""
    if not isinstance(estimator, str) or estimator not in ESTIMATORS:
        raise ConfigError(f"identification.estimator={estimator!r}; valid: {ESTIMATORS} (ls: least squares; iv: "
                          "instrumental variables, for noisy data)")
    require_number(iv_lag, "identification.iv_lag", integer=True)
    if iv_lag < 1:
        raise ConfigError(f"identification.iv_lag={iv_lag}: use an int >= 1 (samples between the instrument and "
                          "the pair)")


def fit_iv_source(train: PairSource, dictionary, config, *, lie=None, m: int = 0, regress: bool = False,
                  fixed_point=None):
    """The IV fit (:func:`~kexp.identify.iv.fit_iv`, or :func:`~kexp.identify.iv.fit_bilinear_iv` if ``regress``)
    of ``train`` with ``config.iv_lag``; ``lie`` None: K only (no input blocks); ``fixed_point``: φ(x_eq), imposed
    as in least squares (kexp.identify.fixed_point)."""
    chunks = pair_chunks(train, config.chunk_size, with_inputs=regress, instrument_lag=config.iv_lag)
    common = dict(method=config.method, rcond=config.rcond, add_constant=dictionary.constant_index is None,
                  lag=config.iv_lag, fixed_point=fixed_point)
    if regress:
        return fit_bilinear_iv(chunks, dictionary.lift, m=m, degree=config.input_degree, **common)
    return fit_iv(chunks, dictionary.lift, lie_inputs=lie, m=m if lie is not None else 0, **common)


def smoothing_window(dataset: PairSource) -> int:
    """The window (samples) of the filter the data were smoothed with before identification (kexp.data.smoothing,
    as the data report states it), 0 if none: the noise left after it is correlated over that many samples."""
    found = re.search(r"window (\d+)", str(getattr(getattr(dataset, "report", None), "smoothing", "") or ""))
    return int(found.group(1)) if found else 0


def _eig_list(lam: np.ndarray) -> list[list[float]]:
    return [[float(v.real), float(v.imag)] for v in lam]


def noise_report(fit, config, dataset: PairSource, train: PairSource, quality: PairSource, dictionary,
                 x_eq: np.ndarray, state_names, *, regress: bool = False) -> tuple[dict, list[str]]:
    """(``report['noise']``, warnings) for a fit made by identify() (see the module docstring)."""
    notes: list[str] = []
    sigma, count = difference_noise(dataset)
    rms = dataset.stats(x_eq).rms
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.where(rms > 0, sigma / rms, np.nan)
    scale = np.ones(dictionary.n) if dictionary.scale is None else np.asarray(dictionary.scale, float)
    center = np.zeros(dictionary.n) if dictionary.center is None else np.asarray(dictionary.center, float)
    lag1 = None
    if dataset.pair_rule == "next" and not quality.forced:
        lag1 = residual_lag1(quality, dictionary.lift, fit.K, dictionary.linear_indices, scale, center).tolist()
    J, lam = linearisation(fit.K, dictionary, x_eq, dataset.dt, dataset.pair_rule)
    out = {"difference_sigma": sigma.tolist(), "relative": rel.tolist(), "n_differences": count,
           "residual_lag1": lag1, "estimator": config.estimator, "pairs_used": fit.n_pairs,
           "linearisation": _eig_list(lam), "complex_pairs": complex_pairs(J), "reference": None}
    noisy = bool(np.nanmax(rel) > NOISE_WARN) if count else False
    worst = int(np.nanargmax(rel)) if count else 0
    window = smoothing_window(dataset)
    if config.estimator == "iv":
        if fit.lag < window:
            notes.append(f"the data were smoothed over {window} samples, so their noise is correlated over as many: "
                         f"the instrument {fit.lag} sample(s) back shares it and IV is biased (measured: Van der Pol, "
                         "3 %, window 11: lag 1 gave 0.71 ± 0.89i, lag 11 0.48 ± 0.88i for 0.5 ± 0.866i); set "
                         f"identification.iv_lag={window} or more, or identify from the unsmoothed data")
        cc = fit.canonical_correlations
        J_ls, lam_ls = linearisation(fit.K_ls, dictionary, x_eq, dataset.dt, dataset.pair_rule)
        out.update(iv_lag=fit.lag, pairs_dropped=int(train.n_pairs - fit.n_pairs),
                   instrument_strength=float(cc.min()) if cc.size else 0.0,
                   reference={"estimator": "ls", "linearisation": _eig_list(lam_ls),
                              "complex_pairs": complex_pairs(J_ls)})
        if not out["instrument_strength"] >= WEAK_INSTRUMENT:
            notes.append(f"weak instruments: the smallest canonical correlation between φ(x(t − {fit.lag}Δ)) and "
                         f"φ(x(t)) is {out['instrument_strength']:.3g} < {WEAK_INSTRUMENT}, where IV eigenvalues were "
                         "measured 8 to 50 % off: the noise is too large for this dictionary or lag; lower "
                         "identification.iv_lag or dictionary.degree, or smooth the data (data.smooth)")
        return out, notes
    if not noisy:
        return out, notes
    name = state_names[worst] if state_names is not None and worst < len(state_names) else f"x{worst + 1}"
    notes.append(f"the data look noisy: a third-difference estimate of the measurement noise is {rel[worst]:.2%} of "
                 f"the data's RMS on {name} (above {NOISE_WARN:.1%}, where least squares measurably biases the "
                 "eigenvalues: errors in variables); consider identification.estimator=iv")
    try:
        ref = fit_iv_source(train, dictionary, replace(config, iv_lag=max(config.iv_lag, window)), m=fit.m,
                            regress=regress)
    except DataError as err:
        notes.append(f"no IV reference to check the fit against: {err}")
        return out, notes
    J_iv, lam_iv = linearisation(ref.K, dictionary, x_eq, dataset.dt, dataset.pair_rule)
    cc = ref.canonical_correlations
    out["reference"] = {"estimator": "iv", "iv_lag": ref.lag, "linearisation": _eig_list(lam_iv),
                        "complex_pairs": complex_pairs(J_iv), "instrument_strength": float(cc.min()) if cc.size
                        else 0.0}
    a, b = out["complex_pairs"], out["reference"]["complex_pairs"]
    if not out["reference"]["instrument_strength"] >= REFERENCE_MIN:
        notes.append(f"the IV reference's instruments are too weak (smallest canonical correlation "
                     f"{out['reference']['instrument_strength']:.3g} < {REFERENCE_MIN}): the fit's linearisation was "
                     "not checked against it")
    elif a != b:
        notes.append(f"the least-squares linearisation at x_eq has {a} complex pair(s) (λ = {fmt_eigs(lam)}), the IV "
                     f"fit on the same data {b} (λ = {fmt_eigs(lam_iv)}): the noise bias has "
                     f"{'lost' if a < b else 'gained'} an oscillation; use identification.estimator=iv")
    return out, notes


def summary_lines(noise: dict | None) -> list[str]:
    """The printed summary's lines for ``report['noise']`` (nothing for a report without one)."""
    if not noise:
        return []
    rel = ", ".join("n/a" if v is None or not np.isfinite(v) else f"{v:.3%}" for v in noise["relative"])
    lines = [f"noise (third differences): σ̂ = " + ", ".join(f"{v:.3g}" for v in noise["difference_sigma"])
             + f" ({rel} of the data's RMS)" + ("" if noise["residual_lag1"] is None else
                "; one-step residuals' lag-1 correlation " + ", ".join(f"{v:+.2f}" for v in noise["residual_lag1"])
                + " (≈ +1 smooth model error, towards −0.5 measurement noise)")]
    lam = np.array([complex(*v) for v in noise["linearisation"]])
    est = noise["estimator"]
    line = f"estimator: {est}"
    if est == "iv":
        line += (f" (lag {noise['iv_lag']}: {noise['pairs_used']} pairs used, {noise['pairs_dropped']} without an "
                 f"instrument dropped; instruments' smallest canonical correlation {noise['instrument_strength']:.4f})")
    line += f"; linearisation at x_eq λ = {fmt_eigs(lam)}"
    ref = noise.get("reference")
    if ref:
        line += (f"; {ref['estimator'].upper()} on the same pairs: λ = "
                 + fmt_eigs(np.array([complex(*v) for v in ref["linearisation"]])))
    lines.append(line)
    return lines
