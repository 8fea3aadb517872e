"""Channels of a kexp run log (MCAP, JSON-schema encoded, one JSON object per message).

Log times are simulation time in nanoseconds, so a repeated run gives byte-identical deterministic channels.
Wall-clock data (solve times, versions) lives on its own channels, which the diff ignores by default.
"""
from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import orjson

NUM = {"type": "number"}
VEC = {"type": "array", "items": NUM}
MAT = {"type": "array", "items": VEC}

CHANNELS: dict[str, dict] = {
    "/config": {"title": "kexp.Config", "type": "object",
                "properties": {"config": {"type": "object"}, "config_hash": {"type": "string"}}},
    "/model": {"title": "kexp.Model", "type": "object",
               "properties": {"eigenvalues_re": VEC, "eigenvalues_im": VEC, "Lambda": MAT,
                              "B": {"type": "array", "items": MAT}, "b": MAT, "C": MAT, "dt": NUM,
                              "k": NUM, "m": NUM, "n": NUM, "state_names": {"type": "array"}, "x_eq": VEC,
                              "report": {"type": "object"}}},
    "/clf": {"title": "kexp.Clf", "type": "object",
             "properties": {"P": MAT, "r": NUM, "r_hat": NUM, "status": {"type": "string"},
                            "certificate": {"type": "object"}, "boundary_r": MAT, "boundary_r_hat": MAT}},
    "/step": {"title": "kexp.Step", "type": "object",
              "properties": {"k": NUM, "t": NUM, "x": VEC, "x_meas": VEC, "z": VEC, "u": VEC, "w": VEC, "V": NUM, "Vdot": NUM,
                             "region": {"type": "string"}, "active": {"type": "string"},
                             "binds": {"type": "boolean"}, "slack": NUM, "status": {"type": "string"},
                             "qp_status": {"type": "string"}, "iterations": NUM, "qp_iterations": NUM,
                             "fallback": {"type": "boolean"}, "reason": {"type": "string"}}},
    "/timing": {"title": "kexp.Timing", "type": "object", "properties": {"k": NUM, "t": NUM, "solve_time": NUM}},
    "/prediction": {"title": "kexp.Prediction", "type": "object",
                    "properties": {"k": NUM, "t": NUM, "t_pred": VEC, "x_pred": MAT}},
    "/open_loop": {"title": "kexp.OpenLoop", "type": "object", "properties": {"t": NUM, "x": VEC}},
    "/summary": {"title": "kexp.Summary", "type": "object",
                 "properties": {"status": {"type": "string"}, "message": {"type": "string"},
                                "metrics": {"type": "object"}, "completed": {"type": "boolean"},
                                "noise": {"type": "object"}, "plant": {"type": "object"}}},
    "/run_info": {"title": "kexp.RunInfo", "type": "object",
                  "properties": {"versions": {"type": "object"}, "timing": {"type": "object"},
                                 "lock": {"type": ["object", "null"]}, "plant": {"type": "object"}}},
}

WALL_CLOCK_CHANNELS = ("/timing", "/run_info")
WALL_CLOCK_FIELDS = ("solve_time", "solve_time_median", "solve_time_p95", "solve_time_p99", "solve_time_max",
                     "wall_time_s")


def plain(obj: Any) -> Any:
    """JSON-safe, deterministic: numpy → lists/floats, NaN/inf → None, tuples → lists, complex → [re, im]."""
    if isinstance(obj, dict):
        return {str(k): plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind in "fiub" and (obj.dtype.kind != "f" or np.isfinite(obj).all()):
            return obj.tolist()  # fast path: already JSON-safe numbers
        return plain(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        f = float(obj)
        return f if math.isfinite(f) else None
    if isinstance(obj, (complex, np.complexfloating)):
        return [plain(obj.real), plain(obj.imag)]
    if obj is None or isinstance(obj, str):
        return obj
    return str(obj)


_DUMPS = json.JSONEncoder(sort_keys=True, separators=(",", ":"), allow_nan=False).encode
_OPTS = orjson.OPT_SORT_KEYS | orjson.OPT_NON_STR_KEYS


def encode(payload: dict) -> bytes:
    """Compact JSON with sorted keys of the values of :func:`plain` (NaN/inf → null; floats as the shortest repr
    that reads back to the same float, like ``repr``).  orjson is ~8× faster than the standard library on a
    step; what it does not know (numpy values, complex numbers, other types) it hands to :func:`plain`, so a
    float32 is written as its exact float64 value either way; the standard library is the last resort (e.g. an
    int beyond 64 bits)."""
    try:
        return orjson.dumps(payload, default=plain, option=_OPTS)
    except TypeError:   # orjson.JSONEncodeError is a TypeError
        return _DUMPS(plain(payload)).encode()
