"""``kexp.fit``: arrays or a folder of recorded runs → a fitted Koopman bilinear model, without a system class.

    model = kexp.fit(X, U, dt=0.01)             # X (T, n) or a list of (T_i, n); U (T_i − 1, m) or None
    x_hat = model.predict(X[0], u=U[:100])     # (101, n)

With inputs the input matrices B, b are regressed from the forced data (``identification.inputs=regression``; G
is never evaluated); without inputs the model has no input model (m = 0: drift only).  Identification is
kexp's :func:`~kexp.identify.identify` on a :class:`~kexp.identify.datasystem.DataSystem`, so the model equals
the one ``identify`` gives with a system class on the same data (tested), and :class:`FittedModel` wraps the
:class:`~kexp.identify.model.KoopmanBilinearModel` (``.model``), saved in its ``.npz`` format (no pickle).
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import scipy.linalg as sla

from ..data.checks import short
from ..errors import ConfigError, DataError, is_number
from .datasystem import DATA_SYSTEM, DataSystem
from .model import KoopmanBilinearModel

_FIXED = ("inputs",)   # chosen from the data, not a setting of kexp.fit


def _dt(dt) -> float:
    if not (is_number(dt) and np.isfinite(dt) and dt > 0):
        raise ConfigError(f"kexp.fit: dt={short(dt)}: give the sampling time in seconds, a finite number > 0")
    return float(dt)


def _trajectories(value, what: str, width_key: str, many: bool | None = None) -> tuple[list[np.ndarray], bool]:
    """(a list of float (T_i, w), whether ``value`` held several trajectories) of a (T, w) array, a 3-D (n_traj, T,
    w) array or a list of (T_i, w) arrays; ``many``: as the states were given (inputs of m = 1 may be (T_i,))."""
    def trajectory_list(v) -> bool:   # a list of (T, w) arrays; a list of rows is one trajectory
        try:
            return isinstance(v, (list, tuple)) and len(v) > 0 and np.ndim(v[0]) >= 2
        except ValueError:   # a ragged first element: reported below
            return True
    if isinstance(value, np.ndarray) and value.ndim == 3:
        many = True
    elif many is None or not isinstance(value, (list, tuple)):
        many = trajectory_list(value)
    items = list(value) if many else [value]
    if not items:
        raise DataError(f"kexp.fit: {what} is empty; give one trajectory (T, {width_key}) or a list of them")
    out = []
    for i, a in enumerate(items):
        name = f"{what}[{i}]" if many else what
        try:
            arr = np.asarray(a, dtype=float)
        except (TypeError, ValueError):
            raise DataError(f"kexp.fit: {name} is not an array of numbers (ragged rows or text?); give a (T, "
                            f"{width_key}) float array") from None
        if arr.ndim == 1 and width_key == "m":
            arr = arr[:, None]
        if arr.ndim != 2:
            raise DataError(f"kexp.fit: {name} has shape {arr.shape}; give a (T, {width_key}) array (one row per "
                            "sample)")
        bad = np.argwhere(~np.isfinite(arr))
        if bad.size:
            r, c = (int(v) for v in bad[0])
            raise DataError(f"kexp.fit: {name}[{r}, {c}] = {arr[r, c]}; every value must be finite: cut the "
                            "trajectory there (give the parts as a list) or fill the gap")
        out.append(arr)
    widths = {a.shape[1] for a in out}
    if len(widths) > 1:
        raise DataError(f"kexp.fit: the trajectories of {what} have {sorted(widths)} columns; give every one with the "
                        f"same {width_key}")
    return out, many


def arrays_dataset(X, U=None, *, dt: float, name: str = DATA_SYSTEM):
    """The :class:`~kexp.data.Dataset` of trajectories ``X`` and inputs ``U`` (see :func:`fit`): runs of different
    lengths padded at the end with masked samples, as recorded runs are (:mod:`kexp.data.files`)."""
    from ..data.dataset import DataReport, Dataset
    dt = _dt(dt)
    xs, many = _trajectories(X, "X", "n")
    for i, x in enumerate(xs):
        if x.shape[0] < 2:
            raise DataError(f"kexp.fit: X{'' if len(xs) == 1 else f'[{i}]'} has {x.shape[0]} sample(s); a trajectory "
                            "needs at least 2")
    us = None
    if U is not None:
        us, _ = _trajectories(U, "U", "m", many)
        if len(us) != len(xs):
            raise DataError(f"kexp.fit: {len(xs)} trajectories in X but {len(us)} in U; give one input array per "
                            "trajectory")
        for i, (x, u) in enumerate(zip(xs, us)):
            if u.shape[0] not in (x.shape[0] - 1, x.shape[0]):
                at = "" if len(xs) == 1 else f"[{i}]"
                raise DataError(f"kexp.fit: U{at} has {u.shape[0]} rows for X{at}'s {x.shape[0]} samples; give "
                                f"{x.shape[0] - 1} (U[k] held over [t_k, t_k+1)) or {x.shape[0]} (the last unused)")
    t_len = max(x.shape[0] for x in xs)
    n = xs[0].shape[1]
    x = np.full((len(xs), t_len, n), np.nan)
    valid = np.zeros((len(xs), t_len), dtype=bool)
    u = None if us is None else np.zeros((len(xs), t_len - 1, us[0].shape[1]))
    for i, xi in enumerate(xs):
        x[i, :xi.shape[0]], valid[i, :xi.shape[0]] = xi, True
        if u is not None:
            u[i, :xi.shape[0] - 1] = us[i][:xi.shape[0] - 1]
    padded = int((~valid).sum())
    report = DataReport(n_traj=len(xs), n_samples=int(valid.size), n_pairs=int((valid[:, :-1] & valid[:, 1:]).sum()),
                        n_masked_samples=padded, n_dropped_traj=0, filter="none", region="none",
                        source=f"{len(xs)} array trajectory(ies)" + (f", {padded} padding sample(s)" if padded else ""))
    return Dataset(t=np.arange(t_len) * dt, x=x, valid=valid, dt=dt, pair_rule="next", system_name=name, u=u,
                   report=report)


def files_dataset(path, *, dt=None, format: str = "auto", name: str = DATA_SYSTEM, equilibrium=None):
    """(streamed recorded runs at ``path``, their layout): n and m from the first run (:mod:`kexp.data.layout`),
    ``dt`` from its time column when None (every run must then have that spacing)."""
    from ..data.layout import run_layout
    from ..data.streaming import open_runs
    layout = run_layout(path, format)
    if dt is None:
        if layout.dt is None or not layout.dt > 0:
            raise DataError(f"kexp.fit: {layout.first} has no time step to read dt from; give dt=")
        dt = layout.dt
    dt = _dt(dt)
    return open_runs(path, n=layout.n, m=max(layout.m, 1), dt=dt, format=format, x_eq=equilibrium), layout


def _config(settings: dict, forced: bool):
    from .identify import IdentifyConfig
    import dataclasses
    valid = sorted(f.name for f in dataclasses.fields(IdentifyConfig) if f.name not in _FIXED)
    for key in settings:
        if key not in valid:
            hint = ("it follows from the data: inputs given → regression, none → no input model" if key in _FIXED
                    else f"valid: {valid}")
            raise ConfigError(f"kexp.fit: unknown setting {key}={short(settings[key])}; {hint}")
    return IdentifyConfig(**settings, inputs="regression" if forced else "projection")


def fit(data, u=None, *, dt=None, degree: int = 5, equilibrium=None, state_names=None, dictionary=None,
        format: str = "auto", name: str = DATA_SYSTEM, **settings) -> "FittedModel":
    """Fit kexp's Koopman bilinear model to trajectories, with no system class.

    ``data``: one trajectory X (T, n), a list of trajectories (T_i, n) (lengths may differ) or a (n_traj, T, n)
    array; or a path (str or Path) to a recorded run or a folder of runs (NPZ, CSV or ``run.mcap``, layouts as in
    :mod:`kexp.data.files`; n and m from the first run, ``dt`` from its times when not given).  ``u``: inputs
    alongside arrays, (T_i − 1, m) per trajectory, U[k] held over [t_k, t_{k+1}) (T_i rows: the last is unused),
    or None.  ``dt``: sampling time in seconds (required for arrays).  ``degree``: monomials of x − x_eq up to
    this degree (``dictionary``: a :class:`~kexp.dictionary.Monomials` instead).  ``equilibrium`` (n,): the state
    the model is centred on (z = Ψ(x) − Ψ(x_eq)); default the origin; it should be an equilibrium of the data's
    dynamics (the drift there is dropped; the summary prints how large it is).  ``settings``: any
    :class:`~kexp.identify.IdentifyConfig` field (holdout, keep, method, input_degree, prediction_horizon, …)
    except ``inputs``, which follows from the data: nonzero inputs → B, b regressed (G never evaluated); no inputs →
    m = 0, no input model.  Bad input raises a one-line :class:`~kexp.errors.DataError` / ConfigError.
    """
    from ..data.runs import check_dictionary_range
    from ..dictionary import Monomials
    from .identify import identify
    if isinstance(data, (str, os.PathLike)):
        if u is not None:
            raise ConfigError("kexp.fit: u= goes with arrays; recorded runs carry their inputs (columns u1…um / "
                              "array u): leave u out")
        if not (isinstance(data, os.PathLike) or data):
            raise ConfigError("kexp.fit: data='' ; give a path to a run or a folder of runs, or arrays")
        dataset, layout = files_dataset(Path(data), dt=dt, format=format, name=name, equilibrium=equilibrium)
        m = layout.m if dataset.forced else 0
        name = layout.system or name
    else:
        if dt is None:
            raise ConfigError("kexp.fit: dt is missing; give the sampling time of the arrays in seconds, e.g. "
                              "dt=0.01")
        dataset = arrays_dataset(data, u, dt=dt, name=name)
        if u is not None and not dataset.forced:
            raise DataError("kexp.fit: U is zero everywhere, so no input model can be regressed; leave U out for a "
                            "drift-only model (m = 0), or give forced runs")
        m = dataset.u.shape[2] if dataset.forced else 0
    system = DataSystem(label=name, n_states=dataset.n, n_inputs=m, x_eq=_equilibrium(equilibrium, dataset.n),
                        names=() if state_names is None else tuple(state_names))
    config = _config(settings, dataset.forced)
    if dictionary is None:
        if not (is_number(degree, integer=True) and degree >= 1):
            raise ConfigError(f"kexp.fit: degree={short(degree)}: use an int >= 1 (monomials up to that degree)")
        center = tuple(system.equilibrium.tolist()) if np.any(system.equilibrium) else None
        dictionary = Monomials(dataset.n, int(degree), center=center)
    elif not isinstance(dictionary, Monomials) or dictionary.n != dataset.n:
        raise ConfigError(f"kexp.fit: dictionary={short(dictionary)}: give a Monomials of the data's n={dataset.n}")
    train, _ = dataset.split(config.holdout, config.holdout_seed)
    need = 2 * dictionary.size
    if train.n_pairs < need:
        raise DataError(f"kexp.fit: {train.n_pairs} training pairs ({dataset.n_pairs} in all, {dataset.n_traj} "
                        f"trajectory(ies), holdout={config.holdout}) for {dictionary.size} dictionary functions "
                        f"(degree {dictionary.degree}, n={dataset.n}): give at least {need} pairs or lower degree")
    check_dictionary_range(dataset.stats(), dictionary.degree, dictionary.scale, dictionary.center)
    return FittedModel(identify(system, dataset, dictionary, config))


def _equilibrium(value, n: int) -> tuple:
    """``equilibrium`` as a tuple of n floats (() for None: the origin); a one-line ConfigError otherwise."""
    if value is None:
        return ()
    try:
        a = np.asarray(value, float).reshape(-1)
    except (TypeError, ValueError):
        a = np.array([np.nan])
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise ConfigError(f"kexp.fit: equilibrium={short(value)}: give {n} finite number(s), one per state, or None "
                          "(the origin)")
    return tuple(a.tolist())


class FittedModel:
    """A fitted Koopman bilinear model (from :func:`fit` or :meth:`load`): ``model`` the
    :class:`~kexp.identify.model.KoopmanBilinearModel` (Λ, B, b, C, the lift, the report), ``n``, ``m``, ``dt``,
    ``eigenvalues`` (continuous, complex (k,)).  Works on any kexp model, e.g. a run's ``model.npz``."""

    def __init__(self, model: KoopmanBilinearModel):
        if not isinstance(model, KoopmanBilinearModel):
            raise ConfigError(f"FittedModel(model={short(model)}): expected a KoopmanBilinearModel")
        self.model = model

    n = property(lambda self: self.model.n)
    m = property(lambda self: self.model.m)
    dt = property(lambda self: self.model.dt)
    eigenvalues = property(lambda self: self.model.eigenvalues)
    report = property(lambda self: self.model.report)

    def __repr__(self) -> str:
        return (f"FittedModel({self.model.system!r}: n={self.n}, m={self.m}, k={self.model.k} eigen-coordinates, "
                f"dt={self.dt:g} s)")

    def summary(self) -> str:
        """The model summary kexp prints (fit, eigenfunctions, held-out prediction error, eigenvalues)."""
        return self.model.summary()

    def _inputs(self, u, steps, duration) -> np.ndarray:
        """(T, m) inputs of a prediction: ``u`` if given (its rows set the number of steps), else zeros."""
        if u is not None:
            if steps is not None or duration is not None:
                raise ConfigError("predict: give u (its rows set the steps) or steps/duration, not both")
            u = np.asarray(u, dtype=float)
            if self.m == 1 and u.ndim == 1:
                u = u[:, None]
            if u.ndim != 2 or u.shape[1] != self.m or self.m == 0:
                raise ConfigError(f"predict: u has shape {u.shape}; this model has m={self.m} input(s)"
                                  + (": leave u out" if self.m == 0 else f": give (T, {self.m})"))
            if not np.all(np.isfinite(u)):
                raise ConfigError("predict: u holds NaN/inf; give finite inputs")
            return u
        if (steps is None) == (duration is None):
            raise ConfigError("predict: give steps= (an int >= 0) or duration= (seconds), or u=")
        if duration is not None:
            if not (is_number(duration) and 0 <= duration < np.inf):
                raise ConfigError(f"predict: duration={short(duration)}: give seconds >= 0")
            steps = int(round(duration / self.dt))
        if not (is_number(steps, integer=True) and steps >= 0):
            raise ConfigError(f"predict: steps={short(steps)}: use an int >= 0")
        return np.zeros((int(steps), self.m))

    def predict(self, x0, u=None, *, steps: int | None = None, duration: float | None = None) -> np.ndarray:
        """The model's prediction from ``x0`` (n,) → (T+1, n), or from a batch (M, n) → (M, T+1, n), row 0 the
        model's reading of x0 (x_eq + C z(x0)).  ``u`` (T, m): inputs held over each Δ (exact matrix exponential
        per step); without ``u``: ``steps`` (T) or ``duration`` (seconds, T = round(duration/Δ)) with u = 0."""
        x0 = np.asarray(x0, dtype=float)
        if x0.ndim not in (1, 2) or x0.shape[-1] != self.n or not np.all(np.isfinite(x0)):
            raise ConfigError(f"predict: x0 has shape {x0.shape}; give ({self.n},) or (M, {self.n}) finite numbers")
        U = self._inputs(u, steps, duration)
        z = np.empty((U.shape[0] + 1,) + x0.shape[:-1] + (self.model.k,))
        z[0] = self.model.lift(x0)
        cache: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}
        for t, ut in enumerate(U):
            key = ut.tobytes()
            if key not in cache:
                cache[key] = self.model.step_matrices(ut) if self.m else (sla.expm(self.model.Lambda * self.dt),
                                                                          np.zeros(self.model.k))
            ad, cd = cache[key]
            z[t + 1] = z[t] @ ad.T + cd
        x = self.model.to_state(z)
        return x if x0.ndim == 1 else np.moveaxis(x, 0, 1)

    def score(self, X, U=None, *, horizon: float = 1.0) -> float:
        """RMSE of the model's ``horizon``-second prediction on trajectories ``X`` (as :func:`fit` takes them;
        inputs ``U`` as recorded, required when m > 0): from every sample x(t_s) with x(t_s + h) in its trajectory
        (h = round(horizon/Δ) steps), predicted under the recorded inputs (exact ZOH), the root of the mean over
        those windows and the n states of (x̂_i(t_s + h) − x_i(t_s + h))², in the units of x."""
        if not (is_number(horizon) and 0 < horizon < np.inf):
            raise ConfigError(f"score: horizon={short(horizon)}: give seconds > 0")
        if self.m and U is None:
            raise ConfigError(f"score: this model has m={self.m} input(s); give the recorded inputs U")
        ds = arrays_dataset(X, U if self.m else None, dt=self.dt)
        if ds.n != self.n:
            raise DataError(f"score: X has n={ds.n} columns; the model has n={self.n}")
        h = max(1, int(round(horizon / self.dt)))
        ad0 = sla.expm(self.model.Lambda * self.dt)
        sq, count = 0.0, 0
        for i in range(ds.n_traj):
            T1 = int(ds.valid[i].sum())
            starts = np.arange(T1 - h)
            if starts.size == 0:
                continue
            z = self.model.lift(ds.x[i, starts])
            for j in range(h):
                if self.m:
                    uj = ds.u[i, starts + j]
                    keys, inv = np.unique(uj, axis=0, return_inverse=True)
                    inv = inv.reshape(-1)
                    nz = np.empty_like(z)
                    for q, key in enumerate(keys):
                        ad, cd = self.model.step_matrices(key)
                        nz[inv == q] = z[inv == q] @ ad.T + cd
                    z = nz
                else:
                    z = z @ ad0.T
            err = self.model.to_state(z) - ds.x[i, starts + h]
            sq += float(np.sum(err ** 2))
            count += err.size
        if count == 0:
            raise DataError(f"score: no trajectory is longer than the horizon ({h} steps of {self.dt:g} s); give "
                            "longer trajectories or a shorter horizon")
        return float(np.sqrt(sq / count))

    def save(self, path) -> Path:
        """Write the model to ``path`` (``.npz``, kexp's model format: arrays and JSON, no pickle); returns it."""
        return self.model.save(path)

    @classmethod
    def load(cls, path) -> "FittedModel":
        """A model saved by :meth:`save` (or a kexp run's ``model.npz``)."""
        return cls(KoopmanBilinearModel.load(path))
