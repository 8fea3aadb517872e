"""The per-step messages of a run log (/step, /timing, /prediction), encoded a flush's worth at a time.

``encode(step_payload(rec))`` is what a /step message holds.  :func:`step_messages` gives the same bytes for a
batch of records from one orjson call (tests/test_steps.py): the payloads are built with their keys already in
sorted order, so orjson need not sort them, and orjson's text of the list of them is cut at each message's first
key.  The cut is safe: orjson writes every ``"`` inside a string as ``\\"``, so the separator ``},{"V":`` cannot
occur inside a message, nor can a message hold a nested object.  One call for a hundred messages saves each
message's call, option handling and key sort (measured in benchmarks/logging_overhead.py's README table).
"""
from __future__ import annotations

import numpy as np
import orjson

from .schema import encode, plain

_ZEROS: dict = {}   # (shape, dtype) -> a list of zeros, the /step "w" of a step without a disturbance (read only)


def _zeros(u: np.ndarray) -> list:
    key = (u.shape, u.dtype)
    zeros = _ZEROS.get(key)
    if zeros is None:
        zeros = _ZEROS[key] = np.zeros(u.shape, u.dtype).tolist()
    return zeros


def step_payload(rec) -> dict:
    """The /step message of a :class:`~kexp.simulate.StepRecord`: its fields as plain numbers, lists and strings
    (``x_meas`` = x when the record has none, ``w`` = zeros like u), its keys in sorted order."""
    u, x_meas, w = rec.u, getattr(rec, "x_meas", None), getattr(rec, "w", None)
    return {"V": float(rec.V), "Vdot": float(rec.Vdot), "active": rec.active, "binds": bool(rec.binds),
            "fallback": bool(rec.fallback), "iterations": int(rec.iterations), "k": int(rec.k),
            "qp_iterations": int(rec.qp_iterations), "qp_status": rec.qp_status, "reason": rec.reason,
            "region": rec.region, "slack": float(rec.slack), "status": rec.status, "t": float(rec.t),
            "u": u.tolist(), "w": _zeros(u) if w is None else np.asarray(w).tolist(), "x": rec.x.tolist(),
            "x_meas": (rec.x if x_meas is None else x_meas).tolist(), "z": np.asarray(rec.z).tolist()}


def timing_payload(rec) -> dict:
    """The /timing message of a step record (wall-clock: the diff ignores it by default), keys in sorted order;
    a paced run's (``sim.realtime``) also has the step's lateness ``late`` (s) and ``miss``."""
    late = getattr(rec, "late", None)
    if late is None:
        return {"k": int(rec.k), "solve_time": float(rec.solve_time), "t": float(rec.t)}
    return {"k": int(rec.k), "late": float(late), "miss": bool(rec.miss), "solve_time": float(rec.solve_time),
            "t": float(rec.t)}


def prediction_payload(rec, Z: np.ndarray, model) -> dict:
    """The /prediction message of a step whose plan is logged: the predicted z over the horizon (Np+1, k) in x."""
    return {"k": rec.k, "t": rec.t, "t_pred": rec.t + model.dt * np.arange(len(Z)), "x_pred": model.to_state(Z)}


def _batch(payloads: list, first_key: str) -> list[bytes]:
    """``encode(p)`` for each payload (plain values, keys in sorted order, the first one ``first_key``), from
    one orjson call; one by one where orjson cannot take them (e.g. an int beyond 64 bits)."""
    if not payloads:
        return []
    try:
        text = orjson.dumps(payloads, default=plain)
    except TypeError:   # orjson.JSONEncodeError is a TypeError
        return [encode(p) for p in payloads]
    head = b'{"' + first_key.encode() + b'":'
    cut = b"}," + head
    return [head + part + b"}" for part in text[1 + len(head):-2].split(cut)]


def step_messages(recs) -> list[bytes]:
    """``encode(step_payload(r))`` for each record, in one pass."""
    return _batch([step_payload(r) for r in recs], "V")


def timing_messages(recs) -> list[bytes]:
    """``encode(timing_payload(r))`` for each record, in one pass."""
    return _batch([timing_payload(r) for r in recs], "k")


def prediction_message(rec, Z: np.ndarray, model) -> bytes:
    """``encode(prediction_payload(rec, Z, model))``: orjson writes float64 arrays itself (the same text as their
    ``tolist()``, a test) instead of handing them to :func:`~kexp.recording.schema.plain`."""
    payload = prediction_payload(rec, Z, model)
    t_pred, x_pred = payload["t_pred"], payload["x_pred"]
    if (type(rec.k) is int and type(rec.t) is float and t_pred.dtype == np.float64 and x_pred.dtype == np.float64
            and x_pred.flags.c_contiguous):
        try:
            return orjson.dumps(payload, option=orjson.OPT_SERIALIZE_NUMPY)
        except TypeError:
            pass
    return encode(payload)


def log_times(recs) -> list[int]:
    """Each record's time stamp in integer nanoseconds, round(t·1e9) (half to even, as Python's ``round``)."""
    return np.rint(np.array([r.t for r in recs], dtype=float) * 1e9).astype(np.int64).tolist()
