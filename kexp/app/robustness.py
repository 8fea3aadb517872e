"""The robustness table: each controller under each perturbation, against the true-model oracle under the same
perturbation, from the committed sweep summaries (results/*.csv, results/robustness/*.csv).

A CSV's conditions are read from its columns (written by ``kexp-results collect`` from each run's summary):
``controller``, ``inputs`` (projection on the known G, or regression), ``sim_noise`` (measurement noise as a
fraction of the data's RMS; the data carry the same), ``smoothing`` (the data's filter before identification:
'raw' or 'SG <window>' in the table), ``mismatch`` (the plant's parameters that differ from the
data's system), ``data_noise`` (when it differs from the loop's, the G column says so), ``estimator`` ('IV' in the G
column) and ``sim_noise_per_x0`` ('per x0': each initial condition its own draw; the oracle and LQR it is
compared with must have drawn the same way).  CSVs written before these columns existed count as unperturbed runs with G known.  The ratio
J / J_oracle is taken per initial condition against the oracle (controller ``nmpc``) with the same noise and
plant; the LQR (true linearisation) and the oracle know the plant, so only the LMPC is data-driven.  A system
with no oracle under any condition (a plant with no formula) says "n/a (no oracle)".  Runs are matched by their
full x0 (x0_1 … x0_n); ``<system>_ocp.csv`` (the plants view's feasibility check) is skipped.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .aggregate import ReportError
from .results import NO_ORACLE, is_ocp, oracle_line, read_csv, split_name, split_stem, x0_columns, x0_key

KINDS = ("lmpc", "lqr", "nmpc")


def _f(v) -> float:
    return float(v) if v not in ("", None) else float("nan")


def _conditions(name: str, row: dict) -> tuple:
    """The run's conditions; its configuration is the file name's (<system>_<configuration>): one that does not
    start with a controller kind (e.g. paper-lmpc, the paper's preset) is no row of this table, whatever
    controller its runs used (a paper-lmpc CSV in today's columns says controller lmpc, as the working preset's)."""
    configured = split_stem(name)[1].split("-")[0]
    controller = configured if configured not in KINDS else (row.get("controller") or configured)
    controller = {"nmpc_oracle": "nmpc", "nmpc_sqp": "nmpc"}.get(controller, controller)
    sim_noise = round(_f(row.get("sim_noise") or 0.0), 6)
    data_noise = row.get("data_noise")
    return (controller, row.get("inputs") or "projection", sim_noise, row.get("smoothing") or "none",
            row.get("mismatch") or "", sim_noise if data_noise in ("", None) else round(_f(data_noise), 6),
            row.get("estimator") or "ls", (row.get("sim_noise_per_x0") or "False") == "True")


def load(paths) -> dict:
    """{(system, controller, inputs, noise, smoothing, mismatch, data noise, estimator, noise per x0): (file name,
    {x0: (success, cost)})} over
    ``paths``;
    raises :class:`ReportError` when a CSV is not a results CSV (:func:`kexp.app.results.read_csv`), mixes
    conditions or two CSVs hold the same ones."""
    out: dict = {}
    unique = {Path(p).resolve(): Path(p) for p in sorted(map(Path, paths), reverse=True)}  # a file given twice
    for p in sorted(unique.values()):
        if is_ocp(p):
            continue
        rows = read_csv(p)
        system = split_name(p)[0]
        keys = {_conditions(p.stem, r) for r in rows if r.get("status") == "completed"} or \
            {_conditions(p.stem, rows[0])}
        if len(keys) > 1:
            raise ReportError(f"{p}: runs under different conditions {sorted(keys)}; one sweep per CSV")
        key = (system, *keys.pop())
        if key[1] not in KINDS:
            continue
        if key in out:
            raise ReportError(f"{p} and {out[key][0]} hold the same runs' conditions {key}; keep one")
        cols = x0_columns(rows[0])
        out[key] = (p.name, {x0_key(r, cols): (r["success"] == "True", _f(r["cost"])) for r in rows})
    return out


def _noise(v: float) -> str:
    return "0" if v == 0 else f"{100 * v:g} %"


def _plant(m: str) -> str:
    return "nominal" if not m else m.replace("mu=", "μ = ").replace("c=", "c = ")


def _cell(runs: dict | None, oracle: dict | None, none: str = "no oracle") -> tuple[str, str]:
    if runs is None:
        return "–", "–"
    succ = f"{sum(s for s, _ in runs.values())}/{len(runs)}"
    if oracle is None:
        return succ, none
    # an x0 counts where both costs are finite and the oracle's is > 0 (a failed oracle run has none to compare)
    ratios = np.array([c / oracle[x][1] for x, (s, c) in runs.items()
                       if x in oracle and np.isfinite(c) and np.isfinite(oracle[x][1]) and oracle[x][1] > 0])
    if ratios.size == 0:
        return succ, "–"
    return succ, f"{np.median(ratios):.3f} / {ratios.max():.3g}"


def table(paths) -> str:
    """The Markdown robustness table: per system and perturbation (G known or regressed, noise, plant), the
    LMPC's and LQR's successes and J / J_oracle (median / worst), and the oracle's successes.  Where no oracle ran
    under a row's noise, the ratios are against the noise-free oracle on the same plant, marked †."""
    data = load(paths)
    lines = ["| system | G | noise σ | plant | LMPC success | LMPC J/J* median / worst | LQR success "
             "| LQR J/J* median / worst | oracle success |",
             "|---|---|---:|---|---:|---:|---:|---:|---:|"]
    conds = sorted({(s, *rest) for (s, c, *rest) in data if c == "lmpc"},
                   key=lambda k: (k[0], k[4] != "", k[1] != "projection", k[7], k[2], k[5], k[3] != "none", k[3],
                                  k[6] != "ls", k[6], k[4]))

    def base(system, controller, noise, mism, per_x0):   # the true-model references ignore the data's treatment
        return next((v[1] for k, v in data.items() if k[:2] == (system, controller) and k[3] == noise
                     and k[5] == mism and k[8] == per_x0), None)

    for system, inputs, noise, smooth, mism, data_noise, estimator, per_x0 in conds:
        lmpc = data[(system, "lmpc", inputs, noise, smooth, mism, data_noise, estimator, per_x0)][1]
        oracle, lqr = base(system, "nmpc", noise, mism, per_x0), base(system, "lqr", noise, mism, per_x0)
        mark = ""
        if oracle is None and noise != 0:  # no oracle under this noise: the noise-free one on the same plant
            oracle = base(system, "nmpc", 0.0, mism, False)
            mark = " †" if oracle is not None else ""
        # no oracle under any condition: a plant with no formula; else none under this row's (e.g. its plant)
        none = "no oracle" if any(k[:2] == (system, "nmpc") for k in data) else NO_ORACLE
        ls, lr = _cell(lmpc, oracle, none)
        qs, qr = _cell(lqr, oracle, none)
        lr, qr = lr + (mark if lr[0].isdigit() else ""), qr + (mark if qr[0].isdigit() else "")
        os_ = ("n/a" if none == NO_ORACLE else "–" if oracle is None or mark
               else f"{sum(s for s, _ in oracle.values())}/{len(oracle)}")
        g = "known" if inputs == "projection" else "regressed"
        if data_noise != 0:   # the data's noise: the loop's unless the row says otherwise
            sm = smooth.replace("Savitzky–Golay, window ", "SG ").split(",")[0]
            g += f", data {'raw' if smooth == 'none' else sm}" + ("" if data_noise == noise else f" {_noise(data_noise)}")
        if estimator != "ls":
            g += f", {estimator.upper()}"
        sigma = _noise(noise) + (" per x0" if per_x0 and noise != 0 else "")
        lines.append(f"| {system} | {g} | {sigma} | {_plant(mism)} | {ls} | {lr} | {qs} | {qr} | {os_} |")
    note = oracle_line(paths)
    return "\n".join(lines + (["", note] if note else []))
