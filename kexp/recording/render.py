"""Render a kexp run log (``run.mcap``) into a Rerun recording (``run.rrd``) with a default blueprint (the blueprint
and the summary document: :mod:`kexp.recording.render_view`).

Headless: the recording goes straight to a file (no viewer, no network, no spawned process).  Timelines:
``sim_time`` (duration, the log time of each message) and ``step`` (sequence, the control step k).

Entities
    states/x{i}, input/u{i}, lyapunov/{V, Vdot, r, r_hat}          time series from /step (+ the /clf levels)
    constraints/{active, binds, slack, fallback}, timing/solve_time_ms   time series from /step, /timing
    timing/{late_ms, miss}                                        a paced run's (sim.realtime) lateness, misses
    phase/{closed_loop, open_loop, start, equilibrium, omega_r, omega_r_hat}   static (n = 2 only)
    phase/state, phase/prediction                                 at their step time: scrubbing shows the plan
    eigenvalues/{lambda, axes}                                    the model's continuous eigenvalues (complex plane)
    summary, config                                               text documents

``kexp-render run.mcap [-o run.rrd]`` is the command-line front end (:func:`main`).
"""
from __future__ import annotations

import hashlib
import json
import os
import sys
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from ..cli import Parser
from ..errors import KexpError
from .reader import RunLog, read_log
from .render_view import default_blueprint, summary_markdown
from .rrd_stream import APPLICATION_ID, RenderError, blueprint_stream, flush

ACTIVE_CODES = {"none": 0.0, "21e": 1.0, "21f": 2.0}   # constraint activity as a number (other values: NaN)

# colours (RGB)
_BLUE, _ORANGE, _GREEN, _RED = (31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40)
_PURPLE, _GRAY, _CYAN, _BROWN = (148, 103, 189), (150, 150, 150), (23, 190, 207), (140, 86, 75)
_PALETTE = [_BLUE, _ORANGE, _GREEN, _RED, _PURPLE, _BROWN, _CYAN, _GRAY]


class RenderWarning(UserWarning):
    """The log was rendered, but it is incomplete (truncated, or the run did not finish)."""


# -- small helpers ---------------------------------------------------------------------------------------------
def _f(v: Any) -> float:
    """A JSON number (``None`` stands for NaN/inf in kexp logs) as a float."""
    try:
        return float(v)
    except (TypeError, ValueError):
        return float("nan")


def _rows(values: list, width: int | None = None) -> np.ndarray:
    """Ragged / None-holed lists of numbers → a float array (N, width), missing entries NaN."""
    rows = [v if isinstance(v, (list, tuple)) else [] for v in values]
    if width is None:
        width = max((len(r) for r in rows), default=0)
    out = np.full((len(rows), width), np.nan)
    for i, r in enumerate(rows):
        for j, v in enumerate(r[:width]):
            out[i, j] = _f(v)
    return out


def _points2(pts: Any) -> np.ndarray:
    """A list of [x1, x2] points → (M, 2) float, dropping malformed / non-finite points."""
    arr = _rows(list(pts or []), 2)
    return arr[np.all(np.isfinite(arr), axis=1)] if arr.size else np.zeros((0, 2))


def _closed(pts: np.ndarray) -> np.ndarray:
    return np.vstack([pts, pts[:1]]) if len(pts) > 2 else pts


def _recording_id(log: RunLog) -> str:
    cfg = log.one("/config") or {}
    chash = cfg.get("config_hash")
    if not chash and isinstance(cfg.get("config"), dict):
        chash = hashlib.sha256(json.dumps(cfg["config"], sort_keys=True).encode()).hexdigest()[:16]
    if not chash:  # no config in the log (cut before its first chunk): derive it from the file itself
        chash = "file-" + hashlib.sha256(log.path.read_bytes()).hexdigest()[:16]
    return f"kexp-{chash}"


def _equilibrium(log: RunLog, n: int) -> np.ndarray:
    """x_eq of the run's system: from /model (logs since x_eq was added), else rebuilt from /config, else 0."""
    xe = np.asarray((log.one("/model") or {}).get("x_eq") or [], dtype=float)
    if xe.shape == (n,) and np.all(np.isfinite(xe)):
        return xe
    cfg = (log.one("/config") or {}).get("config") or {}
    sys_cfg = cfg.get("system") or {}
    try:
        from ..systems import make_system
        xe = np.asarray(make_system(sys_cfg["name"], sys_cfg.get("params") or {}).equilibrium, dtype=float)
        if xe.shape == (n,) and np.all(np.isfinite(xe)):
            return xe
    except Exception:  # noqa: BLE001 - an unknown / changed system: fall back to the origin
        pass
    return np.zeros(n)


def _time_columns(rr, ns: list[int], k: list) -> list:
    return [rr.TimeColumn("sim_time", duration=np.asarray(ns, dtype=np.int64).astype("timedelta64[ns]")),
            rr.TimeColumn("step", sequence=np.asarray([int(_f(v)) if np.isfinite(_f(v)) else i
                                                       for i, v in enumerate(k)], dtype=np.int64))]


def _series(rec, rr, path: str, name: str, color, times: list, values: np.ndarray, *, step: bool = False) -> None:
    rec.log(path, rr.SeriesLines(names=name, colors=[color], widths=1.5,
                                 **({"interpolation_mode": "StepAfter"} if step else {})), static=True)
    rec.send_columns(path, indexes=times, columns=rr.Scalars.columns(scalars=np.asarray(values, dtype=np.float64)))


# -- content ---------------------------------------------------------------------------------------------------
def _log_steps(rec, rr, log: RunLog, names: list[str]) -> dict:
    """Time series of /step and /timing; returns what the phase portrait and the blueprint need."""
    steps = log.channels.get("/step", [])
    info = {"n": 0, "m": 0, "x": np.zeros((0, 0)), "steps": len(steps)}
    if steps:
        ns = [t for t, _ in steps]
        msgs = [m for _, m in steps]
        times = _time_columns(rr, ns, [m.get("k") for m in msgs])
        x = _rows([m.get("x") for m in msgs])
        u = _rows([m.get("u") for m in msgs])
        info.update(n=x.shape[1], m=u.shape[1], x=x, times=times)
        for i in range(x.shape[1]):
            label = f"x{i + 1}" + (f" ({names[i]})" if i < len(names) and names[i] != f"x{i + 1}" else "")
            _series(rec, rr, f"states/x{i + 1}", label, _PALETTE[i % len(_PALETTE)], times, x[:, i])
        for i in range(u.shape[1]):
            _series(rec, rr, f"input/u{i + 1}", f"u{i + 1}", _PALETTE[(i + 3) % len(_PALETTE)], times, u[:, i])
        # measurement noise / disturbance (sim.noise, sim.disturbance): drawn only when the run had them
        if all(m.get("x_meas") is not None for m in msgs):
            xm = _rows([m.get("x_meas") for m in msgs])
            if xm.shape == x.shape and not np.array_equal(xm, x):
                for i in range(x.shape[1]):
                    _series(rec, rr, f"states/x{i + 1}_meas", f"x{i + 1} measured", _GRAY, times, xm[:, i])
        if all(m.get("w") is not None for m in msgs):
            w = _rows([m.get("w") for m in msgs])
            if w.shape == u.shape and np.any(w != 0):
                for i in range(w.shape[1]):
                    _series(rec, rr, f"input/w{i + 1}", f"w{i + 1} (disturbance)", _GRAY, times, w[:, i],
                            step=True)
        _series(rec, rr, "lyapunov/V", "V", _BLUE, times, [_f(m.get("V")) for m in msgs])
        _series(rec, rr, "lyapunov/Vdot", "V̇", _RED, times, [_f(m.get("Vdot")) for m in msgs])
        _series(rec, rr, "constraints/active", "active (0 none, 1 21e, 2 21f)", _PURPLE, times,
                [ACTIVE_CODES.get(m.get("active"), np.nan) for m in msgs], step=True)
        _series(rec, rr, "constraints/binds", "binds", _ORANGE, times,
                [float(bool(m.get("binds"))) for m in msgs], step=True)
        _series(rec, rr, "constraints/slack", "slack", _GREEN, times, [_f(m.get("slack")) for m in msgs])
        _series(rec, rr, "constraints/fallback", "fallback", _RED, times,
                [float(bool(m.get("fallback"))) for m in msgs], step=True)
        # the level-set values r, r̂ as flat lines across the run, for reading V against them
        clf = log.one("/clf") or {}
        ends = _time_columns(rr, [ns[0], ns[-1]], [msgs[0].get("k"), msgs[-1].get("k")])
        for key, name, color in (("r", "r (Ω_r)", _ORANGE), ("r_hat", "r̂ (Ω_r̂)", _PURPLE)):
            level = _f(clf.get(key))
            if np.isfinite(level):
                _series(rec, rr, f"lyapunov/{key}", name, color, ends, [level, level])
    timing = log.channels.get("/timing", [])
    if timing:
        msgs = [m for _, m in timing]
        times = _time_columns(rr, [t for t, _ in timing], [m.get("k") for m in msgs])
        _series(rec, rr, "timing/solve_time_ms", "solve time [ms]", _BROWN, times,
                [_f(m.get("solve_time")) * 1e3 for m in msgs])
        # a paced run's (sim.realtime): each step's lateness (end − deadline; > 0 a miss) and its misses
        if any("late" in m for m in msgs):
            late = [_f(m.get("late")) for m in msgs]
            _series(rec, rr, "timing/late_ms", "lateness [ms] (> 0: missed Δ)", _RED, times, np.asarray(late) * 1e3)
            _series(rec, rr, "timing/miss", "deadline miss", _ORANGE, times,
                    [float(bool(m.get("miss"))) if "miss" in m else np.nan for m in msgs], step=True)
            info["realtime"] = {"steps": len(msgs), "misses": sum(bool(m.get("miss")) for m in msgs),
                                "late_max": float(np.nanmax(late)) if np.any(np.isfinite(late)) else None}
    return info


def _log_phase(rec, rr, log: RunLog, info: dict) -> bool:
    """Phase portrait x1–x2 (n = 2 only).  Returns whether anything was drawn."""
    if info["n"] != 2:
        return False
    radius = rr.Radius.ui_points(1.5)
    x = info["x"]
    good = np.all(np.isfinite(x), axis=1)
    rec.log("phase/closed_loop", rr.LineStrips2D([x[good]], colors=[_BLUE], radii=radius,
                                                 labels=["closed loop"], show_labels=False), static=True)
    if good.any():
        rec.log("phase/start", rr.Points2D(x[good][:1], colors=[_GREEN], radii=rr.Radius.ui_points(5.0),
                                           labels=["x0"]), static=True)
    rec.log("phase/equilibrium", rr.Points2D([_equilibrium(log, 2)], colors=[_RED],
                                             radii=rr.Radius.ui_points(5.0), labels=["x_eq"]), static=True)
    # the current state, at its step time
    rec.send_columns("phase/state", indexes=info["times"], columns=rr.Points2D.columns(positions=x))
    rec.log("phase/state", rr.Points2D.from_fields(colors=[_BLUE], radii=rr.Radius.ui_points(4.0)), static=True)
    ol = log.channels.get("/open_loop", [])
    if ol:
        xo = _rows([m.get("x") for _, m in ol], 2)
        xo = xo[np.all(np.isfinite(xo), axis=1)]
        rec.log("phase/open_loop", rr.LineStrips2D([xo], colors=[_GRAY], radii=radius, labels=["open loop"],
                                                   show_labels=False), static=True)
    clf = log.one("/clf") or {}
    for key, path, color, label in (("boundary_r", "phase/omega_r", _ORANGE, "Ω_r"),
                                    ("boundary_r_hat", "phase/omega_r_hat", _PURPLE, "Ω_r̂")):
        pts = _points2(clf.get(key))
        if len(pts):
            rec.log(path, rr.LineStrips2D([_closed(pts)], colors=[color], radii=radius, labels=[label],
                                          show_labels=False), static=True)
    # predicted horizons, each shown from its step time for `logging.prediction_every` steps (until the next plan)
    pred = log.channels.get("/prediction", [])
    if pred:
        rec.log("phase/prediction", rr.LineStrips2D.from_fields(colors=[_CYAN], radii=rr.Radius.ui_points(2.0)),
                static=True)
        ns, ks, strips, lengths = _prediction_rows(log, pred)
        rec.send_columns("phase/prediction", indexes=_time_columns(rr, ns, ks),
                         columns=rr.LineStrips2D.columns(strips=strips).partition(lengths))
    return True


def _prediction_rows(log: RunLog, pred: list):
    """Rows of phase/prediction: one strip per logged plan, and an empty row (clearing the view) where a plan
    has run out (``prediction_every`` steps later) before the next one is logged."""
    conf = (log.one("/config") or {}).get("config") or {}
    every = (conf.get("logging") or {}).get("prediction_every") or 0
    step_ns = {int(_f(m.get("k"))): t for t, m in log.channels.get("/step", []) if np.isfinite(_f(m.get("k")))}
    ns, ks, strips, lengths = [], [], [], []
    for i, (t, m) in enumerate(pred):
        xp = _rows(list(m.get("x_pred") or []), 2)
        strips.append(xp[np.all(np.isfinite(xp), axis=1)] if xp.size else np.zeros((0, 2)))
        k = _f(m.get("k"))
        ns.append(t)
        ks.append(k)
        lengths.append(1)
        if not (isinstance(every, int) and every > 0 and np.isfinite(k)):
            continue
        k_end = int(k) + every
        next_k = _f(pred[i + 1][1].get("k")) if i + 1 < len(pred) else None
        if (next_k is None or next_k > k_end) and k_end in step_ns:
            ns.append(step_ns[k_end])
            ks.append(k_end)
            lengths.append(0)
    return ns, ks, strips, np.asarray(lengths, dtype=np.int64)


def _log_eigenvalues(rec, rr, log: RunLog) -> bool:
    model = log.one("/model")
    if not model:
        return False
    re = np.asarray([_f(v) for v in model.get("eigenvalues_re") or []])
    im = np.asarray([_f(v) for v in model.get("eigenvalues_im") or []])
    k = min(len(re), len(im))
    lam = np.stack([re[:k], im[:k]], 1)
    lam = lam[np.all(np.isfinite(lam), axis=1)]
    if not len(lam):
        return False
    rec.log("eigenvalues/lambda", rr.Points2D(lam, colors=[_BLUE], radii=rr.Radius.ui_points(4.0),
                                              labels=[f"{a:+.3g}{b:+.3g}i" for a, b in lam], show_labels=False),
            static=True)
    lo, hi = lam.min(0), lam.max(0)
    pad = 0.1 * max(float(np.max(hi - lo)), float(np.max(np.abs(lam))), 1e-3)
    xr = (min(lo[0], 0.0) - pad, max(hi[0], 0.0) + pad)
    yr = (min(lo[1], 0.0) - pad, max(hi[1], 0.0) + pad)
    rec.log("eigenvalues/axes", rr.LineStrips2D([[[xr[0], 0.0], [xr[1], 0.0]], [[0.0, yr[0]], [0.0, yr[1]]]],
                                                colors=[_GRAY], radii=rr.Radius.ui_points(0.75),
                                                labels=["Re", "Im"], show_labels=False), static=True)
    return True


def _phase_bounds(log: RunLog) -> tuple | None:
    """x1, x2 ranges framing the closed loop, x0, x_eq and Ω_r (not the open loop, which may run off far away)."""
    pts = [_rows([m.get("x") for m in log.messages("/step")], 2), _equilibrium(log, 2)[None]]
    clf = log.one("/clf") or {}
    pts += [_points2(clf.get("boundary_r")), _points2(clf.get("boundary_r_hat"))]
    p = np.vstack(pts)
    p = p[np.all(np.isfinite(p), axis=1)]
    if not len(p):
        return None
    lo, hi = p.min(0), p.max(0)
    pad = 0.08 * np.maximum(hi - lo, 1e-3) + 1e-3
    return (float(lo[0] - pad[0]), float(hi[0] + pad[0])), (float(lo[1] - pad[1]), float(hi[1] + pad[1]))


# -- public API ------------------------------------------------------------------------------------------------
def render(mcap_path: str | Path, rrd_path: str | Path | None = None) -> Path:
    """Render the run log at ``mcap_path`` into a Rerun recording at ``rrd_path`` (default: the same path with
    suffix ``.rrd``) and return that path.  A truncated or unfinished log is rendered as far as it goes, with a
    :class:`RenderWarning` carrying the reader's message; a missing / non-MCAP file raises
    :class:`~kexp.recording.reader.LogError`.  The file is written under a temporary name and moved into place
    when complete, so a failed render never leaves a half-written .rrd."""
    import rerun as rr
    import rerun.blueprint as rrb

    mcap_path = Path(mcap_path)
    rrd_path = Path(rrd_path) if rrd_path is not None else mcap_path.with_suffix(".rrd")
    log = read_log(mcap_path)
    if not rrd_path.name or rrd_path.name in (".", ".."):
        raise RenderError(f"output {str(rrd_path)!r} is not a file name; give a path such as run.rrd")
    if rrd_path.resolve() == mcap_path.resolve():
        raise RenderError(f"the recording would overwrite the log {mcap_path}; pass another output path")
    if rrd_path.exists() and not rrd_path.is_file():   # a folder, a device, a pipe: never replaced
        raise RenderError(f"output {rrd_path} exists and is not a regular file; give a file path such as run.rrd")
    if not log.channels.get("/step"):
        raise RenderError(f"{mcap_path} holds no control step (/step) to render"
                          + (f" ({log.warning})" if log.warning else ""))
    if log.warning:
        warnings.warn(log.warning, RenderWarning, stacklevel=2)

    model = log.one("/model") or {}
    names = [str(s) for s in model.get("state_names") or []]
    steps = log.channels.get("/step", [])
    n = max((len(m.get("x") or []) for _, m in steps), default=0)
    blueprint = default_blueprint(rrb, has_phase=n == 2, has_eig=bool(model.get("eigenvalues_re")),
                           has_timing=bool(log.channels.get("/timing")),
                           has_realtime=any("late" in m for _, m in log.channels.get("/timing", [])),
                           phase_bounds=_phase_bounds(log) if n == 2 else None)

    rec = rr.RecordingStream(APPLICATION_ID, recording_id=_recording_id(log))
    if not rec.is_enabled():
        raise RenderError("Rerun is disabled in this environment (RERUN=off): no recording written; "
                          "unset RERUN to render")
    rrd_path.parent.mkdir(parents=True, exist_ok=True)
    tmp = rrd_path.with_name(f".{rrd_path.name}.{os.getpid()}.tmp")
    done = False
    bp_stream = bp_storage = None
    try:
        bp_stream, bp_storage = blueprint_stream(rr, blueprint)
        # rec.save(tmp, default_blueprint=blueprint), with the blueprint's stream in hand
        rr.bindings.save(path=str(tmp), default_blueprint=bp_storage, recording=rec.to_native())
        conf = log.one("/config") or {}
        system = ((conf.get("config") or {}).get("system") or {}).get("name")
        rec.send_recording_name(f"kexp {system or ''} {conf.get('config_hash', '')}".strip())
        info = _log_steps(rec, rr, log, names)
        _log_phase(rec, rr, log, info)
        _log_eigenvalues(rec, rr, log)
        rec.log("summary", rr.TextDocument(summary_markdown(log, info), media_type=rr.MediaType.MARKDOWN),
                static=True)
        rec.log("config", rr.TextDocument(json.dumps(conf.get("config") or {}, indent=2, sort_keys=True),
                                          media_type="text/plain"), static=True)
        flush(rec, rrd_path, tmp)
        done = True
    finally:
        rec.disconnect()   # closes the file sink: the footer is written and the .rrd is complete
        if bp_stream is not None:
            bp_stream.disconnect()   # drops its memory sink: the blueprint stream is no longer kept alive
        del rec, bp_stream, bp_storage
        rr.bindings.flush_and_cleanup_orphaned_recordings()   # drops both streams and ends their threads
        try:
            if done:
                os.replace(tmp, rrd_path)
        finally:
            tmp.unlink(missing_ok=True)   # moved into place, or not: never left behind
    return rrd_path


def _cli(argv: list[str] | None) -> int:
    parser = Parser(prog="kexp-render",
                    description="Render a kexp run log (run.mcap) into a Rerun recording (.rrd).")
    parser.add_argument("mcap", help="the run log, e.g. outputs/<date>/<time>/run.mcap")
    parser.add_argument("-o", "--output", default=None, help="the .rrd to write (default: next to the log)")
    args = parser.parse_args(argv)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RenderWarning)
        try:
            out = render(args.mcap, args.output)
        except (KexpError, OSError) as exc:   # LogError, RenderError, an unwritable output path
            print(f"kexp-render: error: {exc}", file=sys.stderr)
            return 2
    for w in caught:
        if issubclass(w.category, RenderWarning):
            print(f"kexp-render: warning: {w.message}", file=sys.stderr)
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    print(f"wrote {out} ({out.stat().st_size / 1024:.0f} KiB)")
    return 0


def main(argv: list[str] | None = None) -> None:
    """``kexp-render run.mcap [-o run.rrd]``: exits 0 on success (also for a truncated log, after a warning
    line), 2 with one ``kexp-render: error: ...`` line on a missing / unreadable file."""
    sys.exit(_cli(argv))


if __name__ == "__main__":
    main()
