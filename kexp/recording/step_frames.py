"""How a batch of step records travels from the run to the log-writer process (:mod:`kexp.recording.process_log`):
:func:`pack_steps` gives (frame kind, bytes) and :func:`unpack_steps` the records (and logged plans) back, with the
fields :mod:`kexp.recording.steps` reads, so that the child's RunLogger encodes them to the same bytes as the run's
would (tests/test_process_log.py).  One ``pickle`` (protocol 5) of the scalar fields as they are (a numpy scalar
stays one: the child writes it as the run would), each array field's arrays stacked as bytes with their dtype and
shape where they share them (else the values as they are), and the plans."""
from __future__ import annotations

import pickle
from operator import attrgetter

import numpy as np

SCALARS = ("k", "t", "V", "Vdot", "active", "binds", "fallback", "iterations", "qp_iterations", "qp_status",
           "reason", "region", "slack", "status", "solve_time")
ARRAYS = ("u", "x", "z")
OPTIONAL = ("x_meas", "w", "late", "miss")   # read with getattr(rec, name, None), as steps.step_payload does
FIELDS = SCALARS + ARRAYS + OPTIONAL
KIND = b"S"                     # the frame kind of a batch
_scalars = attrgetter(*SCALARS)
_arrays = [attrgetter(f) for f in ARRAYS]
_dtype, _shape, _ndim = attrgetter("dtype"), attrgetter("shape"), attrgetter("ndim")
_ND = np.ndarray


def _stacked(values: list):
    """A batch's arrays of one field as (dtype, shape, their bytes one after the other), or None where they are
    not all numeric arrays of one dtype and shape (all None: ())."""
    first = values[0]
    if first is None:
        return () if all(v is None for v in values) else None
    if type(first) is not _ND or first.dtype.hasobject or set(map(type, values)) != {_ND}:
        return None
    if len(set(map(_dtype, values))) != 1:
        return None
    if first.ndim == 1:     # one dimension each: the lengths say the shapes (len is ~3x cheaper than .shape)
        if len(set(map(_ndim, values))) != 1 or len(set(map(len, values))) != 1:
            return None
    elif len(set(map(_shape, values))) != 1:
        return None
    try:
        data = b"".join(values)     # their buffers, C-contiguous ones only (TypeError otherwise)
    except TypeError:
        data = b"".join(map(np.ndarray.tobytes, values))
    return first.dtype.str, first.shape, data


def _column(values: list):
    """What goes over for one array field: the stacked arrays (:func:`_stacked`), or the list of values as they
    are (arrays of several shapes or dtypes, lists and the like)."""
    stacked = _stacked(values)
    return values if stacked is None else stacked


def _rows(column, n: int) -> list:
    if type(column) is list:
        return column
    if column == ():
        return [None] * n
    dtype, shape, data = column
    return list(np.frombuffer(data, dtype=np.dtype(dtype)).reshape((n,) + tuple(shape)))


def pack_steps(recs: list, plans: list = ()) -> tuple[bytes, bytes]:
    """(frame kind, data) of a batch of records and the plans logged with them, (index in ``recs``, dt, x̂) each:
    ~1.2 µs per step repeated at once (the pickle of the scalars ~0.15, faster than ``marshal`` and its check
    that every value is a Python number or string, which marshal would otherwise turn into bytes)."""
    columns = [_column(list(map(get, recs))) for get in _arrays]
    columns += [_column([getattr(r, f, None) for r in recs]) for f in OPTIONAL]
    return KIND, pickle.dumps((list(map(_scalars, recs)), columns, list(plans)), protocol=5)


class _Record:
    """A step record rebuilt in the writer process: the fields :mod:`kexp.recording.steps` reads."""

    __slots__ = FIELDS

    def __init__(self, values):
        for name, value in zip(FIELDS, values):
            setattr(self, name, value)


class _Plan:
    """What RunLogger.log_step reads of a control step and a model for a logged plan: ``predicted`` (here x̂
    itself) and a model whose ``to_state`` is the identity (x̂ was computed by the caller) and whose ``dt`` is the
    caller's model's."""

    __slots__ = ("predicted", "dt")

    def __init__(self, dt, x_pred):
        self.dt, self.predicted = dt, x_pred

    @staticmethod
    def to_state(Z):
        return Z


def unpack_steps(kind: bytes, data: bytes) -> list:
    """The records (and plans) of :func:`pack_steps`'s data."""
    if kind != KIND:
        raise ValueError(f"not a batch of steps: frame kind {kind!r}")
    scalars, columns, plans = pickle.loads(data)
    n = len(scalars)
    arrays = [_rows(c, n) for c in columns]
    out = [(_Record(values + tuple(a[i] for a in arrays)), None) for i, values in enumerate(scalars)]
    for i, dt, x_pred in plans:
        out[i] = (out[i][0], _Plan(dt, x_pred))
    return out
