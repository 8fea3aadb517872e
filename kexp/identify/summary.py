"""A readable summary of an identified model."""
from __future__ import annotations

import numpy as np

from .noise_check import summary_lines


def _fmt_lam(lam: complex) -> str:
    return f"{lam.real:+.5f}" if lam.imag == 0 else f"{lam.real:+.5f} ± {abs(lam.imag):.5f}i"


def model_summary(model) -> str:
    r = model.report
    lines = [f"Koopman bilinear model of {model.system}: k = {model.k} eigen-coordinates, m = {model.m} input(s), "
             f"n = {model.n} states, Δ = {model.dt:g} s"]
    d = model.dictionary
    lines.append(f"dictionary: monomials up to degree {d.degree}"
                 f"{' (weights ' + str(d.weights) + ')' if d.weights else ''}, {d.size} functions"
                 f"{', with constant' if d.include_constant else ', no constant'}"
                 f"{', scale ' + str(tuple(round(s, 4) for s in d.scale)) if d.scale else ''}"
                 f"{', of x − ' + str(tuple(round(c, 4) for c in d.center)) if d.center else ''}")
    for line in r.get("data", []):
        lines.append("data: " + line)
    if r:
        lines.append(f"fit: {r['method']}, {r['n_pairs_train']} training pairs ({r['pair_rule']} pairs), "
                     f"cond(Φ_X) = {r['cond_phi_x']:.3e} (Gram {r['cond_gram']:.3e}), rank {r['rank']}/"
                     f"{r['dictionary_size']}, relative K residual {r['k_fit_residual']:.2e}")
        lines.append(f"eigenfunctions: kept {r['kept']}, dropped {r['dropped']}, constant eigenfunction "
                     f"{'found (carries the input into b)' if r['constant_eigenfunction'] else 'none'}, "
                     f"eigenvector condition {r['eigvec_cond']:.2e}")
        if r.get("inputs") == "regression":
            vp = r.get("input_vs_projection")
            lines.append(f"inputs: B, b regressed from forced data (input monomials to degree {r['input_degree']}; G "
                         f"not used), lifted next-state residual {r['input_regression_residual']:.2e}"
                         + (f"; vs projection with the true G: |ΔB| {vp['B']:.2e}, |Δb| {vp['b']:.2e}, input field in x "
                              f"{vp['field_x']:.2e} (relative)"
                            if vp else ""))
        if r.get("inputs") == "regression":   # G was never used: its residual is ~0 by construction, no evidence
            lines.append("Assumption 1 (L_G Ψ = BΨ): not checked (G unknown, B regressed); the input model's checks "
                         "are the lifted next-state residual above and the held-out prediction error below")
        elif model.m == 0:   # a system known only from unforced data (kexp.fit, system=data): no input model
            lines.append("inputs: none (m = 0: unforced data and no G, so a drift-only model)")
        else:
            lines.append("Assumption 1 (L_G Ψ = BΨ) relative residual: "
                         + ", ".join(f"{v:.2e}" for v in r["input_projection_residual"])
                         + ("  (dictionary-level: " + ", ".join(f"{v:.2e}" for v in r["dictionary_lie_residual"])
                            + ")" if r.get("dictionary_lie_residual") else ""))
        lines.append(f"drift dropped at the equilibrium: |ΛΨ(x_eq)| = {r['drift_at_equilibrium']:.3e} "
                     f"(in x: {r['drift_at_equilibrium_x']:.3e})"
                     + ("; the fit keeps x_eq fixed (identification.fix_equilibrium)" if r.get("fix_equilibrium")
                        else ""))
        pe = r.get("prediction_error", {})
        lines.append(f"prediction error ({r.get('prediction_data', '?')} trajectories, relative RMS): "
                     + ", ".join(f"{k.replace('_', ' ')} {v:.2%}" for k, v in pe.items()))
        vs = r.get("prediction_vs_fit")
        if vs:   # what deriving the control model (eigen-coordinates, shift, truncation) costs against the raw fit
            lines.append("control model vs its raw fit (same windows, relative RMS): "
                         + ", ".join(f"{k.replace('_', ' ')} {v['model']:.2%} vs {v['fit']:.2%}" for k, v in vs.items()))
        lines += summary_lines(r.get("noise"))
        for w in r.get("warnings", []):
            lines.append("WARNING: " + w)
    lines.append(f"{'#':>3} {'λ (continuous)':>24} {'|λ̃|':>9} {'residual':>9}  |B z| gain")
    shown = set()
    for j in range(model.k):
        b = model.block[j]
        if b in shown:
            continue
        shown.add(b)
        gain = np.linalg.norm(model.B[:, j, :]) if model.m else 0.0
        res = model.residual[j]
        lines.append(f"{j:>3} {_fmt_lam(model.eigenvalues[j]):>24} {abs(model.discrete[j]):9.5f} "
                     f"{'   n/a' if np.isnan(res) else f'{res:9.2e}'}  {gain:.3g}")
    return "\n".join(lines)
