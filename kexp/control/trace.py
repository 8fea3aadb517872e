"""CasADi expressions of a system's F and G traced from its own numpy code, so that the oracles need no
hand-written symbolic model.

:func:`trace_system` calls ``system.drift`` and ``system.input_matrix`` once on a batch of one state, shape (1, n),
whose entries are :class:`_Sym` — a plain Python object wrapping a CasADi SX scalar, with the arithmetic operators
and the methods numpy's object-dtype ufuncs call (``np.sin`` on an object array calls ``.sin()`` of each entry, and
so on).  numpy's indexing, ``stack``, ``concatenate``, ``broadcast_to``, ``einsum`` and ``@`` then work on object arrays as on
numbers, and the result is an SX expression of the same arithmetic.  What cannot be traced — a conversion to
float (``np.asarray(x, dtype=float)``), a comparison or branch on the state (``if x[0] > 0``, ``np.where``), a
function numpy has no object loop for — raises :class:`TraceError` with the reason, and the caller falls back to a
registered model (:func:`kexp.control.oracle.register_symbolic`).  A traced model is used only if it agrees with
the system's numeric F and G at random states (:func:`kexp.control.oracle.symbolic_dynamics` checks it).
"""
from __future__ import annotations

import operator

import numpy as np


class TraceError(Exception):
    """The system's numpy code could not be traced (the message says which operation stopped it)."""


def _ca():
    from .bilinear_nlp import _casadi
    return _casadi()


def _sx(v):
    """The SX of a traced entry: a :class:`_Sym`, a number or a 0-d array of either."""
    if isinstance(v, np.ndarray) and v.shape == ():
        v = v.item()
    if isinstance(v, _Sym):
        return v.e
    if isinstance(v, (bool, np.bool_)):
        raise TraceError("a boolean in the result (a comparison of the state)")
    try:
        return _ca().SX(float(v))
    except (TypeError, ValueError):
        raise TraceError(f"an entry of type {type(v).__name__} in the result") from None


def _binary(op):
    def f(self, other):
        return _Sym(op(self.e, _sx(other)))

    def r(self, other):
        return _Sym(op(_sx(other), self.e))
    return f, r


def _unary(name):
    def f(self):
        return _Sym(getattr(_ca(), name)(self.e))
    return f


class _Sym:
    """An SX scalar that numpy treats as a plain Python object (SX itself implements ``__array_function__``, which
    makes ``np.stack`` and friends refuse a mix of arrays and SX)."""

    __slots__ = ("e",)
    __array_priority__ = -1

    def __init__(self, e):
        self.e = e

    __add__, __radd__ = _binary(operator.add)
    __sub__, __rsub__ = _binary(operator.sub)
    __mul__, __rmul__ = _binary(operator.mul)
    __truediv__, __rtruediv__ = _binary(operator.truediv)
    __pow__, __rpow__ = _binary(operator.pow)

    def __neg__(self):
        return _Sym(-self.e)

    def __pos__(self):
        return self

    def __abs__(self):
        return _Sym(_ca().fabs(self.e))

    def __float__(self):
        raise TraceError("a conversion of the state to float (e.g. np.asarray(x, dtype=float) or float(x[0]))")

    def __bool__(self):
        raise TraceError("a branch on the state's value (if/and/or/np.where on x)")

    def _compare(self, other):
        raise TraceError("a comparison of the state (<, >, ==, np.maximum, np.clip …)")

    __lt__ = __le__ = __gt__ = __ge__ = _compare

    def __eq__(self, other):
        self._compare(other)

    __ne__ = __eq__
    __hash__ = object.__hash__

    # the methods numpy's object loops call
    sin, cos, tan = _unary("sin"), _unary("cos"), _unary("tan")
    arcsin, arccos, arctan = _unary("asin"), _unary("acos"), _unary("atan")
    sinh, cosh, tanh = _unary("sinh"), _unary("cosh"), _unary("tanh")
    arcsinh, arccosh, arctanh = _unary("asinh"), _unary("acosh"), _unary("atanh")
    exp, log, sqrt = _unary("exp"), _unary("log"), _unary("sqrt")
    expm1, log1p = _unary("expm1"), _unary("log1p")
    fabs = absolute = __abs__

    def square(self):
        return _Sym(self.e * self.e)

    def arctan2(self, other):
        return _Sym(_ca().atan2(self.e, _sx(other)))

    def conjugate(self):
        return self


def trace_system(system):
    """``(F, G)``: SX expressions (n×1, n×m) of ``system``'s drift and input matrix at the SX symbol ``x`` (n×1), and
    ``x``; raises :class:`TraceError` saying what stopped the trace."""
    ca = _ca()
    n, m = system.n, system.m
    x = ca.SX.sym("x", n)
    xs = np.empty((1, n), dtype=object)
    for i in range(n):
        xs[0, i] = _Sym(x[i])
    try:
        with np.errstate(all="ignore"):
            F = np.asarray(system.drift(xs), dtype=object)
            G = np.asarray(system.input_matrix(xs), dtype=object)
    except TraceError:
        raise
    except Exception as exc:  # noqa: BLE001 - any failure of the user's code on traced values means 'not traceable'
        raise TraceError(f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}") from None
    if F.shape not in ((1, n), (n,)) or G.shape not in ((1, n, m), (n, m)):
        raise TraceError(f"drift gave shape {F.shape} and input_matrix {G.shape} for a batch of one state; "
                         f"need (1, {n}) and (1, {n}, {m})")
    F = F.reshape(n)
    G = G.reshape(n, m)
    Fe = ca.vertcat(*[_sx(v) for v in F])
    Ge = ca.SX(n, m)
    for i in range(n):
        for j in range(m):
            Ge[i, j] = _sx(G[i, j])
    return x, Fe, Ge
