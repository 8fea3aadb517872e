"""The certificate checks that V bounds the state (kexp/clf/bound.py, issue 34 item 4): a decrease of V says
nothing about x unless V(x) ≥ c‖x − x_eq‖² with c large enough against V's size in the region."""
import numpy as np
import pytest
from hydra import compose, initialize_config_dir

from kexp.app.aggregate import _short_verdict
from kexp.app.conf import CONF_DIR
from kexp.clf import ClfConfig, QuadraticLyapunov, clf_from_P, synthesize_clf
from kexp.clf.bound import GAIN_MAX, region_scaled, state_bound
from kexp.clf.synthesis import load_clf, save_clf
from kexp.control import make_law
from kexp.data import Circle, DataConfig, collect
from kexp.dictionary import Monomials
from kexp.errors import ConfigError
from kexp.identify import identify
from kexp.systems.library import Linear

from toy import toy_model


@pytest.fixture(scope="module")
def unstable():
    """ẋ1 = 0.5x1 + 0.2u, ẋ2 = −x2 + u, identified from 20 unforced 10-s runs from the unit circle (x1 grows to
    ~150: its eigen-coordinate at unit RMS is 0.03·x1), V from the paper's SDP on the eigen-coordinates."""
    s = Linear(A=((0.5, 0.0), (0.0, -1.0)), B=((0.2,), (1.0,)))
    model = identify(s, collect(s, Circle(20, 1.0), DataConfig(T=10.0)), Monomials(2, 1))
    return s, model, synthesize_clf(model, ClfConfig())


def test_a_v_blind_to_a_diverging_state_is_not_a_clf_in_x(unstable):
    """The issue's case: h decreases V at every sampled state (the verdict before said so), V falls more than 3
    decades in closed loop while x1 leaves the region past 13; the certificate now says "not a CLF in x", and c,
    its direction, λ_min(JᵀPJ) and the gain equal a computation from V's quadratic form in x on an own grid."""
    s, model, clf = unstable
    c = clf.certificate
    assert c.holds_on_samples and c.frac_decrease == 1.0 and not c.global_holds   # the decrease holds
    assert not c.bounds_state and c.verdict.startswith("not a CLF in x: V is nearly blind to the state along (1, ")
    assert "whatever the decrease" in c.verdict and _short_verdict(c.to_dict()) == "not in x"
    assert c.lines()[-1].endswith("> 20: not a CLF in x")
    # independent: the lift is linear, z = Lx, so V = xᵀMx with M = LᵀPL
    L = np.stack([model.lift(e) for e in np.eye(2)], axis=1)
    M = L.T @ clf.P @ L
    g = np.linspace(-1.0, 1.0, 41)
    X = np.array([(a, b) for a in g for b in g if (a, b) != (0.0, 0.0)])
    q = np.einsum("mi,ij,mj->m", X, M, X) / np.sum(X * X, axis=1)
    assert c.c_x == pytest.approx(q.min(), rel=1e-9) and c.c_x < 1e-4
    i = np.argmin(q)
    assert np.allclose(np.abs(c.flat_direction), np.abs(X[i]) / np.linalg.norm(X[i]), atol=1e-12)
    w, v = np.linalg.eigh(M)
    assert c.c_local == pytest.approx(w[0], rel=1e-9)
    assert abs(abs(np.dot(c.flat_direction_local, v[:, 0])) - 1) < 1e-12
    assert c.bound_gain == pytest.approx(np.sqrt(q.max() / q.min()), rel=1e-9) and c.bound_gain > 50 * GAIN_MAX
    # the closed loop: Sontag's h on the true system (held 0.01 s, Euler at 1 ms) from (0.5, 0.5)
    h = make_law("sontag", clf.lyap, -5.0, 5.0, model=model)
    x = np.array([0.5, 0.5])
    V0 = clf.lyap.value(model.lift(x))
    for _ in range(1000):
        u = h(model.lift(x[None]))[0]
        for _ in range(10):
            x = x + 1e-3 * s.rhs(x, u)
        if abs(x[0]) > 13:
            break
    assert abs(x[0]) > 13 and clf.lyap.value(model.lift(x)) < 1e-3 * V0   # measured 4.3e-4


@pytest.mark.parametrize("gain2,holds", [(400.0, True), (np.nextafter(20.0, 0) ** 2, True),
                                         (np.nextafter(20.0, 21) ** 2, False), (100.0, True)])
def test_the_criterion_at_its_boundary(gain2, holds):
    """γ = sqrt(max q / min q) with q = V/‖x̃‖²: at exactly GAIN_MAX = 20 (q = 1 and 400) V bounds the state, γ one
    ulp above 20 does not; x̃ scales each side of the box by its own extent (low = −2, high = 0.5 here)."""
    model = toy_model(np.diag([-1.0, -1.0]), np.zeros((2, 2)), b=[1.0, 0.0])
    lyap = QuadraticLyapunov.from_model(model, np.eye(2))
    x = np.array([[0.5, 0.0], [0.0, -2.0], [-1.0, 0.0]])         # x̃ = (1, 0), (0, −1), (−0.5, 0)
    b = state_bound(model, lyap, x, np.array([1.0, gain2, 0.25]), (-2.0, -2.0), (0.5, 0.5))
    assert b.holds is holds and b.gain == np.sqrt(gain2) and GAIN_MAX == 20.0
    assert np.sqrt(np.nextafter(20.0, 21) ** 2) > 20.0 > np.sqrt(np.nextafter(20.0, 0) ** 2)   # the cases straddle
    assert b.c == 0.25 / 1.0 and b.direction == (1.0, 0.0)         # V/‖x‖²: 4, gain2/4, 0.25; sign made +
    assert b.c_local == 1.0                                        # JᵀPJ = I


def test_region_scaled_divides_each_side_by_its_extent():
    dx = np.array([[0.5, -3.0], [-2.0, 0.0], [0.25, 1.5]])
    assert np.array_equal(region_scaled(dx, (-2.0, -3.0), (0.5, 1.5)), [[1.0, -1.0], [-1.0, 0.0], [0.5, 1.0]])
    assert np.array_equal(region_scaled(np.array([[0.0, 1.0]]), (0.0, -1.0), (1.0, 2.0)), [[0.0, 0.5]])


def test_a_region_without_the_equilibrium_is_refused():
    with pytest.raises(ConfigError, match=r"the box of x − x_eq must hold the equilibrium: need region_low <= 0 "
                                          r"<= region_high"):
        ClfConfig(region_low=(0.1, -1.0), region_high=(1.0, 1.0))
    ClfConfig(region_low=(0.0, -1.0), region_high=(1.0, 1.0))    # x_eq on the box's side: accepted


def test_a_round_v_bounds_the_state_and_a_flat_one_does_not():
    """An identity lift with P = diag(1, p): γ = sqrt(p) on the grid of [−1, 1]² (axes sampled); p = 100
    bounds the state (γ = 10), p = 900 does not (γ = 30), whatever the decrease (h decreases V everywhere)."""
    model = toy_model(np.diag([-1.0, -2.0]), np.zeros((2, 2)), b=[1.0, 1.0])
    for p, holds in ((100.0, True), (900.0, False)):
        c = clf_from_P(model, np.diag([1.0, p]), ClfConfig(grid=21)).certificate
        assert c.holds_on_samples and c.bounds_state is holds
        assert c.bound_gain == pytest.approx(np.sqrt(p), rel=1e-12) and c.c_x == pytest.approx(1.0, rel=1e-12)
        assert c.flat_direction == (1.0, 0.0) and c.flat_direction_local == (1.0, 0.0)
        assert c.verdict.startswith("not a CLF in x") is (not holds)


def test_the_fields_survive_save_and_load_and_an_old_file_gets_them(unstable, tmp_path):
    """to_dict → save_clf → load_clf gives the same report; a file written before the fields existed gets them
    computed from P on the region's samples (equal to check_certificate's)."""
    import json
    _, model, clf = unstable
    save_clf(clf, tmp_path / "c.npz")
    assert load_clf(tmp_path / "c.npz", model, clf.config).certificate == clf.certificate
    with np.load(tmp_path / "c.npz") as f:
        meta = json.loads(str(f["meta"]))
    for key in ("c_x", "flat_direction", "c_local", "flat_direction_local", "bound_gain", "bounds_state"):
        del meta["certificate"][key]
    np.savez(tmp_path / "old.npz", P=clf.P, meta=np.array(json.dumps(meta)))
    assert load_clf(tmp_path / "old.npz", model, clf.config).certificate == clf.certificate


PRESETS = {"vanderpol": 1.2056, "pendulum": 1.3699, "duffing": 4.3428, "cart_pendulum": 3.5916,
           "paper_vanderpol": 2.0160, "paper_pendulum": 4.0239}


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_the_presets_v_bounds_the_state(preset):
    """The shipped presets' V (their model, CLF, law and region): γ as measured (≤ 4.4, well below 20), so their
    verdicts are the ones they had before the bound was checked."""
    from kexp.app import experiment as E
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg = compose(config_name="config", overrides=[f"+experiment={preset}"])
    system = E.build_system(E.config_dict(cfg)["system"])
    sampler, data_cfg = E.build_data(cfg["data"])
    dataset = E.collect(system, sampler, data_cfg)
    model = E.identify(system, dataset, E.build_dictionary(cfg["dictionary"], system.n, dataset, system.equilibrium),
                       E.build_identification(cfg["identification"]))
    spec = E.build_controller_spec(cfg["controller"])
    c = E.synthesize_clf(model, E.build_clf(cfg["clf"]), law=spec.law, u_min=spec.u_min, u_max=spec.u_max,
                         law_params=spec.law_params).certificate
    assert c.bounds_state and c.bound_gain == pytest.approx(PRESETS[preset], rel=1e-3)
    assert _short_verdict(c.to_dict()) == ("samples" if c.holds_on_samples else "fails")
    assert c.verdict.startswith("Proposition 1 FAILS globally" if c.holds_on_samples else "NOT a certified CLF")


def test_the_docs_command_of_the_blind_v_prints_what_the_docs_say(tmp_path):
    """docs/method.md "CLF and certificate": its command, run as written (plus a run folder), prints the verdict and the
    failed run it quotes."""
    import re
    import subprocess
    from pathlib import Path

    from cli import console_script
    text = (Path(__file__).resolve().parents[1] / "docs" / "method.md").read_text(encoding="utf-8")
    sec = text[text.index("\n## CLF and certificate"):text.index("\n## Lyapunov MPC")]
    block = re.search(r"```console\n(kexp system=linear .*?)\ncertificate: (.*?)\n", sec, flags=re.S)
    command = block.group(1).replace("\\\n", " ")
    import shlex
    args = shlex.split(command)[1:] + [f"hydra.run.dir={tmp_path / 'run'}", "logging.rrd=false",
                                       "cache.enabled=false", "logging.progress=false"]
    proc = subprocess.run([console_script("kexp"), *args], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "certificate: " + block.group(2) in proc.stdout
    assert "result: unsettled (completed) — ‖x(T)‖ = 6.05e+01" in proc.stdout
