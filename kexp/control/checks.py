"""Construction-time checks shared by the controllers (:class:`~kexp.control.lmpc.Lmpc`, the explicit and LQR
controllers, the IPOPT oracles and the explicit laws): the input bounds, and that the model, the CLF and the law
fit one another.  Each raises :class:`~kexp.errors.ConfigError` with one line naming what is wrong and what to do;
nothing here runs per control step."""
from __future__ import annotations

import warnings

import numpy as np

from ..errors import ConfigError


def _show(value) -> str:
    return repr(value.tolist()) if isinstance(value, np.ndarray) else repr(value)


def input_bounds(u_min, u_max, m: int, where: str = "controller") -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi): ``u_min``, ``u_max`` (numbers, or m numbers each: one per input) as new float (m,) arrays.
    Raises ConfigError ('<where>.u_min=…, <where>.u_max=…: need finite u_min < u_max') unless both are numbers
    that broadcast to (m,), all finite, with u_min < u_max in every input."""
    out = []
    for key, value in (("u_min", u_min), ("u_max", u_max)):
        try:
            raw = np.asarray(value) if not isinstance(value, (str, bytes)) else None
        except ValueError:   # a ragged list
            raw = None
        if raw is None or raw.dtype.kind not in "iuf" or raw.ndim > 1 or raw.size not in (1, m):
            per = f" or {m} numbers (one per input)" if m > 1 else " (the model has 1 input)"
            raise ConfigError(f"{where}.{key}={_show(value)}: give a number{per}")
        out.append(np.broadcast_to(np.asarray(value, dtype=float), (m,)).copy())
    lo, hi = out
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(lo < hi)):
        raise ConfigError(f"{where}.u_min={_show(u_min)}, {where}.u_max={_show(u_max)}: need finite u_min < u_max")
    return lo, hi


def _need(obj, attrs, what: str, fix: str) -> None:
    missing = [a for a in attrs if not hasattr(obj, a)]
    if obj is None or missing:
        raise ConfigError(f"{what}={type(obj).__name__ if obj is not None else None} lacks "
                          f"{', '.join(missing) or 'everything'}: {fix}")


def check_clf(clf, who: str) -> None:
    """``clf`` must be a CLF: P, lyap, r, r_hat (a :class:`~kexp.clf.Clf`)."""
    _need(clf, ("P", "lyap", "r", "r_hat"), f"{who}: clf", "pass the Clf of synthesize_clf/load_clf")


def check_clf_and_law(clf, law, who: str, model=None) -> None:
    """``clf`` must be a CLF (P, lyap, r, r_hat) — of ``model`` if given: P (k, k) and m inputs — and ``law`` a
    callable z (..., k) -> u (..., m); a law that exposes its ``lyap`` (kexp's laws) must be built on the CLF's V
    (the same P)."""
    check_clf(clf, who)
    if model is not None:
        k_clf, m_clf = np.shape(clf.P), getattr(clf.lyap, "m", model.m)
        if k_clf != (model.k, model.k) or m_clf != model.m:
            raise ConfigError(f"{who}: the CLF is on k={k_clf[0] if k_clf else '?'} eigen-coordinates and m={m_clf} "
                              f"input(s), the model has k={model.k}, m={model.m}: synthesise the CLF for this model "
                              "(synthesize_clf(model, ...))")
    if not callable(law):
        raise ConfigError(f"{who}: law={law!r} is not callable: pass make_law(name, clf.lyap, u_min, u_max)")
    lyap = getattr(law, "lyap", None)
    if lyap is not None and lyap is not clf.lyap and not np.array_equal(getattr(lyap, "P", None), clf.P):
        raise ConfigError(f"{who}: the law ({getattr(law, 'name', type(law).__name__)}) is built on another "
                          f"Lyapunov function than the CLF's (its P {np.shape(getattr(lyap, 'P', None))} is not "
                          f"clf.P {np.shape(clf.P)}): build it with make_law(name, clf.lyap, u_min, u_max)")


def check_model_parts(model, clf, law, u_min, u_max, who: str) -> tuple[np.ndarray, np.ndarray]:
    """The model (k eigen-coordinates, m inputs), the CLF and the law of an LMPC must fit one another
    (:func:`check_clf_and_law`); returns the controller's bounds as :func:`input_bounds` gives them.  A law whose
    own bounds differ from the controller's gets a warning, not an error: (21f) then asks for the decrease of a law
    the controller's inputs may not reach (those steps fall back to h), but a test may narrow the LMPC's bounds on
    purpose (to force a (21e) slack)."""
    _need(model, ("k", "m", "n", "Lambda", "B", "b", "C", "dt"), f"{who}: model",
          "pass the identified model (kexp.identify.identify or KoopmanBilinearModel.load)")
    lo, hi = input_bounds(u_min, u_max, model.m)
    check_clf_and_law(clf, law, who, model)
    law_lo, law_hi = getattr(law, "u_min", None), getattr(law, "u_max", None)
    if law_lo is not None and law_hi is not None and not (np.array_equal(law_lo, lo) and np.array_equal(law_hi, hi)):
        warnings.warn(f"{who}: the law's bounds {_show(np.asarray(law_lo))}..{_show(np.asarray(law_hi))} differ "
                      f"from the controller's {_show(lo)}..{_show(hi)}: (21f) asks for the law's decrease, which "
                      "the controller's inputs may not reach (those steps fall back to h); build the law with the "
                      "controller's bounds", UserWarning, stacklevel=3)
    return lo, hi


def check_lmpc_config(c, state_costs, iterate_when, solvers) -> None:
    """The checks of :class:`~kexp.control.lmpc.LmpcConfig` ``c`` (its ``__post_init__``), each a ConfigError
    naming ``controller.lmpc.<key>``, the value and what is valid."""
    from ..errors import require_number
    from .blocking import block_sizes
    key = "controller.lmpc."
    for name in ("w", "r", "terminal", "tol", "slack_weight", "qp_eps"):
        require_number(getattr(c, name), key + name)
    for name in ("horizon", "max_iter", "qp_max_iter"):
        require_number(getattr(c, name), key + name, integer=True)
    if c.horizon < 1:
        raise ConfigError(f"{key}horizon={c.horizon}: use an int >= 1")
    if not (c.w > 0 and c.r > 0 and np.isfinite(c.w) and np.isfinite(c.r)):
        raise ConfigError(f"lmpc weights w={c.w}, r={c.r}: both must be finite and > 0 ({key}w, {key}r)")
    if c.state_cost not in state_costs:
        raise ConfigError(f"{key}state_cost={c.state_cost!r}; valid: {state_costs}")
    if not (c.terminal >= 0 and np.isfinite(c.terminal)):
        raise ConfigError(f"{key}terminal={c.terminal}: use a finite number >= 0")
    if c.max_iter < 1:
        raise ConfigError(f"{key}max_iter={c.max_iter}: use an int >= 1 (1 = real-time iteration)")
    if not (c.tol > 0 and np.isfinite(c.tol)):
        raise ConfigError(f"{key}tol={c.tol}: use a finite step size > 0 (the SQP stops when no input moves more)")
    if c.iterate_when not in iterate_when:
        raise ConfigError(f"{key}iterate_when={c.iterate_when!r}; valid: {iterate_when}")
    if not (c.slack_weight > 0 and np.isfinite(c.slack_weight)):
        raise ConfigError(f"{key}slack_weight={c.slack_weight}: use a finite number > 0")
    for name in ("use_21e", "use_21f"):
        if not isinstance(getattr(c, name), (bool, np.bool_)):
            raise ConfigError(f"{key}{name}={getattr(c, name)!r}: use true or false")
    if c.qp_solver not in solvers:
        raise ConfigError(f"{key}qp_solver={c.qp_solver!r}; valid: {solvers}")
    if not (c.qp_eps > 0 and np.isfinite(c.qp_eps)):
        raise ConfigError(f"{key}qp_eps={c.qp_eps}: use a finite tolerance > 0 (default 1e-8)")
    if c.qp_max_iter < 1:
        raise ConfigError(f"{key}qp_max_iter={c.qp_max_iter}: use an int >= 1 (default 100)")
    block_sizes(c.horizon, c.free_moves, c.blocks)  # validates the blocking
