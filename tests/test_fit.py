"""kexp.fit: arrays or a folder of runs → a fitted model without a system class (kexp/identify/estimator.py)."""
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg as sla

import kexp
from kexp.data import Box, DataConfig, collect
from kexp.data.excitation import Excitation
from kexp.data.files import write_runs
from kexp.dictionary import Monomials
from kexp.errors import ConfigError, DataError, KexpError
from kexp.identify import IdentifyConfig, identify
from kexp.identify.model import _ARRAYS
from kexp.systems import make_system

# the docs' example (docs/guides/data-from-files.md, "From arrays or a folder to a model: kexp.fit"): arrays → model → prediction, 7 lines
PAGE = Path(__file__).resolve().parents[1] / "docs" / "guides" / "data-from-files.md"
_SECTION = PAGE.read_text(encoding="utf-8").split("\n## From arrays or a folder to a model: `kexp.fit`", 1)[1]
EXAMPLE = re.findall(r"```python\n(.*?)```", _SECTION, flags=re.S)[0]

MU, LAM, DT = -0.7, 0.4, 0.01


def slow_manifold_runs(n_traj=20, steps=200, seed=0):
    """Exact trajectories of ẋ1 = μx1, ẋ2 = λ(x2 − x1²): x1 = a e^{μt}, x2 = (b − c a²) e^{λt} + c a² e^{2μt}."""
    t = np.arange(steps + 1) * DT
    c = LAM / (LAM - 2 * MU)
    out = []
    for a, b in np.random.default_rng(seed).uniform(-1, 1, (n_traj, 2)):
        out.append(np.stack([a * np.exp(MU * t), (b - c * a * a) * np.exp(LAM * t) + c * a * a * np.exp(2 * MU * t)],
                            axis=1))
    return out


@pytest.fixture(scope="module")
def forced():
    vdp = make_system("vanderpol")
    ds = collect(vdp, Box(20, -2.0, 2.0), DataConfig(T=3.0, seed=7, excitation=Excitation(low=-1.0, high=1.0,
                                                                                           hold=10)))
    assert ds.valid.all() and ds.forced
    return vdp, ds


def test_the_readme_example_is_seven_lines_and_runs(capsys):
    assert len(EXAMPLE.strip().splitlines()) <= 7
    ns: dict = {}
    exec(compile(EXAMPLE, "docs/guides/data-from-files.md (kexp.fit)", "exec"), ns)
    model, X = ns["model"], ns["X"]
    for lam in (MU, LAM, 2 * MU):   # solve_ivp at rtol 1e-12: the invariant subspace's eigenvalues to ~1e-9
        assert np.min(np.abs(model.eigenvalues - lam)) < 1e-7
    assert ns["x_hat"].shape == (201, 2)
    assert np.max(np.abs(ns["x_hat"] - X[0])) < 1e-7   # x1, x2 lie in the exact span: the prediction is exact
    assert "-0.7" in capsys.readouterr().out


def test_slow_manifold_eigenvalues_exact_from_clean_data():
    """{1, x1, x2, x1²} is Koopman invariant: degree-2 monomials contain it, so μ, λ, 2μ are eigenvalues of the
    fit exactly (the other two, of x1x2 and x2², are not: their residuals are large) and x = C z predicts exactly."""
    X = slow_manifold_runs()
    model = kexp.fit(X, dt=DT, degree=2)
    assert model.m == 0 and model.n == 2 and model.model.B.shape == (0, model.model.k, model.model.k)
    for lam in (MU, LAM, 2 * MU):
        assert np.min(np.abs(model.eigenvalues - lam)) < 1e-8
    exact = [j for j in range(model.model.k) if model.model.residual[j] < 1e-10]
    assert sorted(model.eigenvalues[exact].real.round(6)) == [2 * MU, MU, LAM]
    assert model.score(X, horizon=2.0) < 1e-10
    assert "inputs: none (m = 0" in model.summary()


def test_forced_fit_equals_identify_with_the_system(forced):
    """The same data as arrays: kexp.fit gives identify()'s model with the Van der Pol class bit for bit (B, b
    regressed in both; G never evaluated by kexp.fit), and identify(None, ...) does too."""
    vdp, ds = forced
    ref = identify(vdp, ds, Monomials(2, 3), IdentifyConfig(inputs="regression"))
    got = kexp.fit(list(ds.x), list(ds.u), dt=ds.dt, degree=3)
    assert got.m == 1
    for a in _ARRAYS:
        assert np.array_equal(getattr(ref, a), getattr(got.model, a)), a
    flat = kexp.fit(list(ds.x), [u[:, 0] for u in ds.u], dt=ds.dt, degree=3)   # m = 1: inputs as (T,) each
    assert flat.model == got.model
    none = identify(None, ds, Monomials(2, 3), IdentifyConfig(inputs="regression"))
    assert all(np.array_equal(getattr(ref, a), getattr(none, a)) for a in _ARRAYS) and none.system == "vanderpol"
    x_ref, _ = ref.predict(ds.x[3, 0], ds.u[3])
    x_got = got.predict(ds.x[3, 0], u=ds.u[3])
    assert x_got.shape == (301, 2)
    assert np.max(np.abs(x_got - x_ref)) <= 1e-12 * np.max(np.abs(x_ref))


def test_save_load_round_trip_is_bit_exact(forced, tmp_path):
    _, ds = forced
    fitted = kexp.fit(list(ds.x), list(ds.u), dt=ds.dt, degree=3)
    path = fitted.save(tmp_path / "m.npz")
    back = kexp.FittedModel.load(path)
    assert back.model == fitted.model   # every array and setting exactly
    assert back.report["prediction_error"] == fitted.report["prediction_error"]
    assert np.array_equal(back.predict(ds.x[0, 0], u=ds.u[0]), fitted.predict(ds.x[0, 0], u=ds.u[0]))
    with np.load(path, allow_pickle=False) as z:   # no pickle inside
        assert set(z.files) == {"meta", *_ARRAYS}


def test_predict_shapes_and_refusals(forced):
    _, ds = forced
    fitted = kexp.fit(list(ds.x), list(ds.u), dt=ds.dt, degree=3)
    assert fitted.predict(ds.x[0, 0], u=ds.u[0, :50]).shape == (51, 2)
    assert fitted.predict(ds.x[0, 0], u=ds.u[0, :50, 0]).shape == (51, 2)     # (T,) for m = 1
    batch = fitted.predict(ds.x[:4, 0], u=ds.u[0, :10])
    assert batch.shape == (4, 11, 2)
    assert np.allclose(batch[2], fitted.predict(ds.x[2, 0], u=ds.u[0, :10]), rtol=0, atol=1e-13)
    free = fitted.predict(ds.x[0, 0], duration=0.5)
    assert free.shape == (51, 2) and np.array_equal(free, fitted.predict(ds.x[0, 0], steps=50))
    assert np.array_equal(free, fitted.predict(ds.x[0, 0], u=np.zeros((50, 1))))
    for kwargs, fragment in (({}, "give steps="), ({"u": np.zeros((5, 2))}, "m=1"), ({"steps": -1}, "steps=-1"),
                             ({"u": ds.u[0], "steps": 3}, "not both")):
        with pytest.raises(ConfigError, match=fragment):
            fitted.predict(ds.x[0, 0], **kwargs)
    drift_only = kexp.fit(slow_manifold_runs(), dt=DT, degree=2)
    with pytest.raises(ConfigError, match="m=0 input.*leave u out"):
        drift_only.predict([0.1, 0.2], u=np.zeros((3, 1)))


def test_score_is_the_rmse_of_the_h_step_prediction(forced):
    """score() against the windows computed one by one with KoopmanBilinearModel.predict (exact ZOH per step)."""
    _, ds = forced
    fitted = kexp.fit(list(ds.x), list(ds.u), dt=ds.dt, degree=3)
    X, U = list(ds.x[:3]), list(ds.u[:3])
    h = 20
    errs = []
    for x, u in zip(X, U):
        for s in range(x.shape[0] - h):
            pred, _ = fitted.model.predict(x[s], u[s:s + h])
            errs.append(pred[-1] - x[s + h])
    want = np.sqrt(np.mean(np.square(errs)))
    assert len(errs) == 3 * (301 - h)
    assert fitted.score(X, U, horizon=h * ds.dt) == pytest.approx(want, rel=1e-10)
    assert 0.005 < want < 0.5    # a real error: Van der Pol is not exact in degree 3
    # unforced: e^{ΛhΔ} on z, computed apart
    X = slow_manifold_runs(n_traj=3, steps=50, seed=1)
    drift = kexp.fit(slow_manifold_runs(), dt=DT, degree=1)   # degree 1: x2's x1² is missing, a visible error
    m, h = drift.model, 10
    ad = sla.expm(m.Lambda * h * DT)
    errs = [m.to_state(m.lift(x[:-h]) @ ad.T) - x[h:] for x in X]
    want = np.sqrt(np.mean(np.square(np.concatenate(errs))))
    assert want > 1e-4
    assert drift.score(X, horizon=h * DT) == pytest.approx(want, rel=1e-10)


def test_a_folder_of_runs_gives_the_arrays_model(forced, tmp_path):
    """CSV runs written by kexp: n, m and dt read from the files; the model equals the one from the arrays (the
    streamed QR equals the in-memory one to rounding)."""
    _, ds = forced
    write_runs(ds, tmp_path / "runs", "csv")
    from_files = kexp.fit(tmp_path / "runs", degree=3)
    from_arrays = kexp.fit(list(ds.x), list(ds.u), dt=ds.dt, degree=3)
    assert (from_files.n, from_files.m, from_files.dt) == (2, 1, 0.01)   # dt read from the times
    for a in ("Lambda", "B", "b", "C"):
        ref = getattr(from_arrays.model, a)
        assert np.max(np.abs(getattr(from_files.model, a) - ref)) <= 1e-10 * max(1.0, np.max(np.abs(ref))), a
    with pytest.raises(ConfigError, match="u= goes with arrays"):
        kexp.fit(tmp_path / "runs", np.zeros((3, 1)))


def _one_line(exc_info) -> str:
    msg = str(exc_info.value)
    assert "\n" not in msg and isinstance(exc_info.value, KexpError)
    return msg


@pytest.mark.parametrize("args,kwargs,kind,fragment", [
    (([np.zeros((10, 2)), np.zeros((10, 3))],), {"dt": 0.1}, DataError, "[2, 3] columns"),
    (([[0.0, 1.0], [2.0]],), {"dt": 0.1}, DataError, "ragged rows"),
    ((np.array([[0.0, 1.0], [np.nan, 1.0], [0.5, 0.5]]),), {"dt": 0.1}, DataError, "X[1, 0] = nan"),
    ((np.ones((50, 2)),), {"dt": 0.0}, ConfigError, "dt=0.0"),
    ((np.ones((50, 2)),), {"dt": -1}, ConfigError, "dt=-1"),
    ((np.ones((50, 2)),), {}, ConfigError, "dt is missing"),
    ((np.ones((20, 2)),), {"dt": 0.1}, DataError, "19 training pairs"),
    ((np.ones((50, 2)), np.ones((30, 1))), {"dt": 0.1}, DataError, "U has 30 rows for X's 50 samples"),
    ((np.ones((50, 2)), np.zeros((49, 1))), {"dt": 0.1}, DataError, "U is zero everywhere"),
    ((np.ones((50, 2)),), {"dt": 0.1, "inputs": "projection"}, ConfigError, "follows from the data"),
    ((np.ones((50, 2)),), {"dt": 0.1, "equilibrium": [0.0]}, ConfigError, "equilibrium=[0.0]: give 2"),
])
def test_bad_input_is_one_line_naming_what_to_fix(args, kwargs, kind, fragment):
    with pytest.raises(kind) as exc:
        kexp.fit(*args, **kwargs)
    assert fragment in _one_line(exc)


def test_a_folder_without_runs_is_one_line(tmp_path):
    (tmp_path / "notes.txt").write_text("no runs here")
    with pytest.raises(DataError) as exc:
        kexp.fit(tmp_path, dt=0.01)
    assert "holds no" in _one_line(exc) and str(tmp_path) in str(exc.value)


def test_import_kexp_stays_lazy():
    code = ("import sys, kexp; "
            "print('kexp.identify.estimator' in sys.modules, 'numpy' in sys.modules, callable(kexp.fit))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["False", "False", "True"]


def test_identify_without_a_system_class():
    """identify(None, …) on unforced data: a drift-only model (m = 0), G never asked for; a DataSystem that
    declares an input but has no G is refused in one line where the projection would need G."""
    from kexp.identify.datasystem import DataSystem
    vdp = make_system("vanderpol")
    ds = collect(vdp, Box(12, -2.0, 2.0), DataConfig(T=2.0))
    free = identify(None, ds, Monomials(2, 3))
    ref = identify(vdp, ds, Monomials(2, 3))   # the same drift, with the class (B projected from its G)
    assert free.m == 0 and ref.m == 1 and free.system == "vanderpol"
    for a in ("Lambda", "C", "eigenvalues"):   # the QR of [Φ_X | Φ_Y] vs [Φ_X | Φ_Y | L_GΦ]: equal to rounding
        want = getattr(ref, a)
        assert np.max(np.abs(getattr(free, a) - want)) <= 1e-10 * np.max(np.abs(want)), a
    with pytest.raises(ConfigError) as exc:
        identify(DataSystem(label="vanderpol", n_states=2, n_inputs=1), ds, Monomials(2, 3))
    assert "G is unknown; identify from forced runs" in _one_line(exc)
