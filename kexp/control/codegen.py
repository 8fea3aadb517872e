"""The true dynamics compiled: a system's symbolic F(x) + G(x)u (CasADi SX, from :mod:`kexp.control.trace` or the
registry) written out as straight-line Python source and compiled by numba, with the sample-and-hold RK4 map and
its exact derivatives (the RK4 scheme differentiated: the variational equations integrated by the same RK4).

:func:`compiled_dynamics` returns a module with

* ``rhs(x, u, f)`` — f ← F(x) + G(x)u, x (n,), u (m,), f (n,);
* ``rhs_jac(x, u, f, J)`` — f as above and J (n, n+m) ← [∂f/∂x | ∂f/∂u];
* ``rollout(x0, U, bos, h, substeps, X)`` — X (N+1, n): X[0] = x0, X[j+1] = RK4 over Δ = h·substeps from X[j]
  with the input U[bos[j]] held (U (nb, m) block inputs, bos (N,) the block of each step);
* ``rollout_jac(x0, U, bos, h, substeps, X, AB)`` — the rollout and AB (N, n, n+m) = [∂X[j+1]/∂X[j] | ∂X[j+1]/∂u_j].

The source is generated from CasADi's instruction list of the SX Function (one assignment per instruction, so
common subexpressions are shared as CasADi shares them), named by its SHA-256 and written once to
``<kexp cache>/generated/`` (atomically: a temporary file renamed); numba caches the compiled functions beside its
other kernels (:mod:`kexp.control.jit_cache`), so a system compiles once per install.  An operation without a
translation here raises :class:`~kexp.errors.ConfigError` naming it.
"""
from __future__ import annotations

import hashlib
import importlib.util
import os
import sys
import tempfile
from pathlib import Path

from ..errors import ConfigError

# CasADi op name -> a Python expression of the inputs a, b (numba compiles math.* and these operators)
_OPS = {
    "ADD": "{a} + {b}", "SUB": "{a} - {b}", "MUL": "{a} * {b}", "DIV": "{a} / {b}", "NEG": "-{a}",
    "ASSIGN": "{a}", "TWICE": "2.0 * {a}", "SQ": "{a} * {a}", "INV": "1.0 / {a}",
    "POW": "{a} ** {b}", "CONSTPOW": "{a} ** {b}", "SQRT": "math.sqrt({a})", "EXP": "math.exp({a})",
    "LOG": "math.log({a})", "SIN": "math.sin({a})", "COS": "math.cos({a})", "TAN": "math.tan({a})",
    "ASIN": "math.asin({a})", "ACOS": "math.acos({a})", "ATAN": "math.atan({a})", "ATAN2": "math.atan2({a}, {b})",
    "SINH": "math.sinh({a})", "COSH": "math.cosh({a})", "TANH": "math.tanh({a})", "ASINH": "math.asinh({a})",
    "ACOSH": "math.acosh({a})", "ATANH": "math.atanh({a})", "EXPM1": "math.expm1({a})", "LOG1P": "math.log1p({a})",
    "FABS": "abs({a})", "HYPOT": "math.hypot({a}, {b})", "ERF": "math.erf({a})", "FLOOR": "math.floor({a})",
    "CEIL": "math.ceil({a})", "FMOD": "math.fmod({a}, {b})", "COPYSIGN": "math.copysign({a}, {b})",
    "FMIN": "min({a}, {b})", "FMAX": "max({a}, {b})",
    "SIGN": "(1.0 if {a} > 0.0 else (-1.0 if {a} < 0.0 else 0.0))",
    "IF_ELSE_ZERO": "({b} if {a} != 0.0 else 0.0)",
    "LT": "(1.0 if {a} < {b} else 0.0)", "LE": "(1.0 if {a} <= {b} else 0.0)",
    "EQ": "(1.0 if {a} == {b} else 0.0)", "NE": "(1.0 if {a} != {b} else 0.0)",
    "NOT": "(1.0 if {a} == 0.0 else 0.0)",
    "AND": "(1.0 if ({a} != 0.0 and {b} != 0.0) else 0.0)", "OR": "(1.0 if ({a} != 0.0 or {b} != 0.0) else 0.0)",
}

_RK4 = '''

@njit(cache=True, nogil=True)
def rollout(x0, U, bos, h, substeps, X):
    n = x0.shape[0]
    k1 = np.empty(n); k2 = np.empty(n); k3 = np.empty(n); k4 = np.empty(n); xt = np.empty(n); x = np.empty(n)
    X[0, :] = x0
    for j in range(bos.shape[0]):
        u = U[bos[j]]
        x[:] = X[j]
        for s in range(substeps):
            rhs(x, u, k1)
            for i in range(n):
                xt[i] = x[i] + 0.5 * h * k1[i]
            rhs(xt, u, k2)
            for i in range(n):
                xt[i] = x[i] + 0.5 * h * k2[i]
            rhs(xt, u, k3)
            for i in range(n):
                xt[i] = x[i] + h * k3[i]
            rhs(xt, u, k4)
            for i in range(n):
                x[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
        X[j + 1, :] = x


@njit(cache=True, nogil=True)
def _stage(x, S, u, a, k, dk, J, xt, St, n, w):
    """k, dk <- f and its derivative at x + a*k_prev (xt, St hold that point and its sensitivity)."""
    rhs_jac(xt, u, k, J)
    for i in range(n):
        for c in range(w):
            acc = J[i, c] if c >= n else 0.0
            for l in range(n):
                acc += J[i, l] * St[l, c]
            dk[i, c] = acc


@njit(cache=True, nogil=True)
def rollout_jac(x0, U, bos, h, substeps, X, AB):
    n = x0.shape[0]
    m = U.shape[1]
    w = n + m
    k1 = np.empty(n); k2 = np.empty(n); k3 = np.empty(n); k4 = np.empty(n); xt = np.empty(n); x = np.empty(n)
    d1 = np.empty((n, w)); d2 = np.empty((n, w)); d3 = np.empty((n, w)); d4 = np.empty((n, w))
    S = np.empty((n, w)); St = np.empty((n, w)); J = np.empty((n, w))
    X[0, :] = x0
    for j in range(bos.shape[0]):
        u = U[bos[j]]
        x[:] = X[j]
        S[:, :] = 0.0
        for i in range(n):
            S[i, i] = 1.0
        for s in range(substeps):
            xt[:] = x
            St[:, :] = S
            _stage(x, S, u, 0.0, k1, d1, J, xt, St, n, w)
            for i in range(n):
                xt[i] = x[i] + 0.5 * h * k1[i]
                for c in range(w):
                    St[i, c] = S[i, c] + 0.5 * h * d1[i, c]
            _stage(x, S, u, 0.5, k2, d2, J, xt, St, n, w)
            for i in range(n):
                xt[i] = x[i] + 0.5 * h * k2[i]
                for c in range(w):
                    St[i, c] = S[i, c] + 0.5 * h * d2[i, c]
            _stage(x, S, u, 0.5, k3, d3, J, xt, St, n, w)
            for i in range(n):
                xt[i] = x[i] + h * k3[i]
                for c in range(w):
                    St[i, c] = S[i, c] + h * d3[i, c]
            _stage(x, S, u, 1.0, k4, d4, J, xt, St, n, w)
            for i in range(n):
                x[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
                for c in range(w):
                    S[i, c] += h / 6.0 * (d1[i, c] + 2.0 * d2[i, c] + 2.0 * d3[i, c] + d4[i, c])
        X[j + 1, :] = x
        AB[j, :, :] = S
'''


def _body(fn, outputs: list[str]) -> list[str]:
    """Straight-line statements of the SX Function ``fn`` (inputs x, u; outputs named ``outputs``, written dense)."""
    import casadi as ca
    names = {getattr(ca, k): k[3:] for k in dir(ca) if k.startswith("OP_")}
    dense = []      # per output: nz index -> (row, col)
    for o in range(fn.n_out()):
        rows, cols = fn.sparsity_out(o).get_triplet()
        dense.append(list(zip(rows, cols)))
    lines = []
    for o, name in enumerate(outputs):   # outputs are written only at their structural non-zeros
        if fn.size2_out(o) == 1:
            lines.append(f"    {name}[:] = 0.0")
        else:
            lines.append(f"    {name}[:, :] = 0.0")
    ins = ("x", "u")
    for k in range(fn.n_instructions()):
        op = names.get(fn.instruction_id(k), str(fn.instruction_id(k)))
        i_in, i_out = fn.instruction_input(k), fn.instruction_output(k)
        if op == "CONST":
            lines.append(f"    w{i_out[0]} = {float(fn.instruction_constant(k))!r}")
        elif op == "INPUT":
            lines.append(f"    w{i_out[0]} = {ins[i_in[0]]}[{i_in[1]}]")
        elif op == "OUTPUT":
            o, nz = i_out
            r, c = dense[o][nz]
            target = f"{outputs[o]}[{r}]" if fn.size2_out(o) == 1 else f"{outputs[o]}[{r}, {c}]"
            lines.append(f"    {target} = w{i_in[0]}")
        elif op in _OPS:
            a = f"w{i_in[0]}"
            b = f"w{i_in[1]}" if len(i_in) > 1 else ""
            lines.append(f"    w{i_out[0]} = " + _OPS[op].format(a=a, b=b))
        else:
            raise ConfigError(f"oracle: the system's dynamics use the operation {op}, which kexp cannot compile; "
                              f"use controller.solver=ipopt for this system")
    return lines


def generate_source(x, u, f) -> str:
    """Python source of the module described in the module docstring, for SX symbols x (n), u (m) and the SX
    right-hand side f (n×1) = F(x) + G(x)u."""
    import casadi as ca
    fun = ca.Function("rhs", [x, u], [f])
    jac = ca.Function("rhs_jac", [x, u], [f, ca.jacobian(f, ca.vertcat(x, u))])
    n, m = x.numel(), u.numel()
    src = ['"""Generated by kexp.control.codegen (the true dynamics for the SQP oracle); do not edit."""',
           "import math", "", "import numpy as np", "from numba import njit", "", f"N_STATES = {n}",
           f"N_INPUTS = {m}", "", "", "@njit(cache=True, nogil=True)", "def rhs(x, u, f):"]
    src += _body(fun, ["f"])
    src += ["", "", "@njit(cache=True, nogil=True)", "def rhs_jac(x, u, f, J):"]
    src += _body(jac, ["f", "J"])
    return "\n".join(src) + "\n" + _RK4


def _folder() -> Path:
    from .jit_cache import cache_dir
    return cache_dir() / "generated"


def compiled_dynamics(x, u, f):
    """Import (generating and writing it first if needed) the compiled module for the right-hand side f(x, u);
    see :func:`generate_source`.  An unwritable cache folder falls back to a temporary one (then the module
    compiles in every process)."""
    src = generate_source(x, u, f)
    digest = hashlib.sha256(src.encode()).hexdigest()[:20]
    name = f"kexp_dynamics_{digest}"
    if name in sys.modules:
        return sys.modules[name]
    path = None
    for folder in (_folder(), Path(tempfile.gettempdir()) / "kexp-generated"):
        try:
            folder.mkdir(parents=True, exist_ok=True)
            path = folder / f"{name}.py"
            if not path.exists() or path.read_text() != src:
                fd, tmp = tempfile.mkstemp(dir=folder, suffix=".tmp")
                with os.fdopen(fd, "w") as fh:
                    fh.write(src)
                os.replace(tmp, path)
            break
        except OSError:
            path = None
    if path is None:
        raise ConfigError("oracle: could not write the generated dynamics module to the kexp cache or the temporary "
                          "folder; set KEXP_CACHE_DIR to a writable folder")
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module
