"""Bad input to kexp.control and kexp.clf is refused at construction in one line that names the field, the value and
what to fix (a tester's calls: they were silent, or failed later inside numpy).  Valid input behaves as before: the
other control and CLF tests (golden recordings, IPOPT agreement) check that."""
import dataclasses
import math
import warnings
from types import SimpleNamespace

import numpy as np
import pytest

from kexp.clf import ClfConfig, clf_from_P, load_clf, save_clf, synthesize_clf
from kexp.control import ExplicitController, Lmpc, LmpcConfig, LqrController, make_law
from kexp.control.blocking import block_sizes
from kexp.data import Circle, DataConfig, collect
from kexp.dictionary import Monomials
from kexp.errors import ClfError, ConfigError
from kexp.identify import identify
from kexp.simulate import closed_loop
from kexp.systems import VanDerPol

nan, inf = math.nan, math.inf
SMALL = LmpcConfig(horizon=20, free_moves=2, blocks=5)


@pytest.fixture(scope="module")
def fx(tmp_path_factory):
    s = VanDerPol()
    data = collect(s, Circle(30, 2.0), DataConfig(T=3.0))
    model = identify(s, data, Monomials(2, 3))
    clf = synthesize_clf(model, ClfConfig())
    model5 = identify(s, data, Monomials(2, 2))
    clf5 = synthesize_clf(model5, ClfConfig())
    tmp = tmp_path_factory.mktemp("clf")
    model.save(tmp / "model.npz")
    return SimpleNamespace(s=s, model=model, clf=clf, h=make_law("sontag", clf.lyap, -5.0, 5.0), model5=model5,
                           clf5=clf5, tmp=tmp)


def lmpc(f, lo=-5.0, hi=5.0, cfg=SMALL, **kw):
    return Lmpc(f.model, f.clf, f.h, cfg, lo, hi, **kw)


CASES = [
    # -- input bounds: one shared check for every controller and law
    ("lqr reversed", lambda f: LqrController(f.s, 5.0, -5.0), ConfigError,
     "controller.u_min=5.0, controller.u_max=-5.0: need finite u_min < u_max"),
    ("lmpc equal bounds", lambda f: lmpc(f, lo=2.0, hi=2.0), ConfigError,
     "controller.u_min=2.0, controller.u_max=2.0: need finite u_min < u_max"),
    ("lqr nan", lambda f: LqrController(f.s, nan, nan), ConfigError, "need finite u_min < u_max"),
    ("lqr q inf", lambda f: LqrController(f.s, -5.0, 5.0, q=inf), ConfigError, "q=inf, r=1.0: both must be finite"),
    ("lmpc -inf", lambda f: lmpc(f, lo=-inf), ConfigError, "controller.u_min=-inf, controller.u_max=5.0: need finite"),
    ("lmpc str", lambda f: lmpc(f, lo="a"), ConfigError, "controller.u_min='a': give a number"),
    ("lmpc two bounds, m=1", lambda f: lmpc(f, lo=[-1.0, -2.0]), ConfigError,
     "controller.u_min=[-1.0, -2.0]: give a number (the model has 1 input)"),
    ("law str bound", lambda f: make_law("sontag", f.clf.lyap, "a", 5.0), ConfigError, "controller.u_min='a'"),
    ("law two bounds", lambda f: make_law("sontag", f.clf.lyap, [-1, -2], 5.0), ConfigError,
     "controller.u_min=[-1, -2]: give a number"),
    ("law empty bound", lambda f: make_law("sontag", f.clf.lyap, np.array([]), 5.0), ConfigError,
     "controller.u_min=[]"),
    # -- Lmpc: its parts must fit
    ("lmpc clf of another model", lambda f: Lmpc(f.model, f.clf5, f.h, SMALL, -5.0, 5.0), ConfigError,
     "the CLF is on k=5 eigen-coordinates and m=1 input(s), the model has k=9"),
    ("lmpc law on another lyap", lambda f: Lmpc(f.model, f.clf, make_law("sontag", f.clf5.lyap, -5.0, 5.0), SMALL,
                                                -5.0, 5.0), ConfigError,
     "built on another Lyapunov function than the CLF's"),
    ("lmpc law None", lambda f: Lmpc(f.model, f.clf, None, SMALL, -5.0, 5.0), ConfigError, "law=None is not callable"),
    ("lmpc clf None", lambda f: Lmpc(f.model, None, f.h, SMALL, -5.0, 5.0), ConfigError, "Lmpc: clf=None lacks"),
    ("lmpc config None", lambda f: Lmpc(f.model, f.clf, f.h, None, -5.0, 5.0), ConfigError,
     "config=None: pass an LmpcConfig"),
    ("lmpc prediction_every -1", lambda f: lmpc(f, prediction_every=-1), ConfigError,
     "prediction_every=-1: use an int >= 0"),
    ("lmpc prediction_every 2.7", lambda f: lmpc(f, prediction_every=2.7), ConfigError,
     "prediction_every=2.7: expected an integer"),
    ("explicit law on another lyap", lambda f: ExplicitController(make_law("sontag", f.clf5.lyap, -5, 5), f.clf),
     ConfigError, "ExplicitController: the law (sontag) is built on another Lyapunov function"),
    ("explicit without a model", lambda f: closed_loop(f.s, ExplicitController(f.h, f.clf), [0.5, 0.1]), ConfigError,
     "pass closed_loop(..., model=<its model>)"),
    # -- LmpcConfig
    ("qp_eps -1", lambda f: LmpcConfig(qp_eps=-1.0), ConfigError, "controller.lmpc.qp_eps=-1.0: use a finite"),
    ("qp_eps 0", lambda f: LmpcConfig(qp_eps=0.0), ConfigError, "controller.lmpc.qp_eps=0.0"),
    ("qp_eps nan", lambda f: LmpcConfig(qp_eps=nan), ConfigError, "controller.lmpc.qp_eps=nan"),
    ("qp_max_iter 0", lambda f: LmpcConfig(qp_max_iter=0), ConfigError, "controller.lmpc.qp_max_iter=0: use an int"),
    ("qp_max_iter -5", lambda f: LmpcConfig(qp_max_iter=-5), ConfigError, "controller.lmpc.qp_max_iter=-5"),
    ("tol -1", lambda f: LmpcConfig(tol=-1.0), ConfigError, "controller.lmpc.tol=-1.0: use a finite step size > 0"),
    ("tol nan", lambda f: LmpcConfig(tol=nan), ConfigError, "controller.lmpc.tol=nan"),
    ("tol 0", lambda f: LmpcConfig(tol=0.0), ConfigError, "controller.lmpc.tol=0.0"),
    ("slack_weight inf", lambda f: LmpcConfig(slack_weight=inf), ConfigError,
     "controller.lmpc.slack_weight=inf: use a finite number > 0"),
    ("free_moves 2.5", lambda f: LmpcConfig(free_moves=2.5), ConfigError,
     "controller.lmpc.free_moves=2.5: expected an integer"),
    ("use_21e 'no'", lambda f: LmpcConfig(use_21e="no"), ConfigError,
     "controller.lmpc.use_21e='no': use true or false"),
    ("horizon True", lambda f: LmpcConfig(horizon=True), ConfigError, "controller.lmpc.horizon=True: expected an int"),
    ("blocks '3'", lambda f: LmpcConfig(blocks="3"), ConfigError, "controller.lmpc.blocks='3': expected an integer"),
    ("free_moves == blocks", lambda f: LmpcConfig(horizon=20, blocks=5), ConfigError,
     "controller.lmpc.free_moves=5 == controller.lmpc.blocks=5 < horizon=20 leaves steps 6..20 without a block"),
    ("free_moves > blocks", lambda f: LmpcConfig(free_moves=8, blocks=4), ConfigError,
     "controller.lmpc.free_moves=8 > controller.lmpc.blocks=4"),
    ("free_moves -1", lambda f: LmpcConfig(free_moves=-1), ConfigError,
     "controller.lmpc.free_moves=-1: use an int >= 0"),
    ("blocks 0", lambda f: LmpcConfig(blocks=0), ConfigError, "controller.lmpc.blocks=0: use an int >= 1"),
    # -- make_law
    ("sontag eps -1", lambda f: make_law("sontag", f.clf.lyap, -5, 5, eps=-1), ConfigError,
     "controller.law_params.eps=-1: use a finite threshold >= 0"),
    ("sontag eps nan", lambda f: make_law("sontag", f.clf.lyap, -5, 5, eps=nan), ConfigError,
     "controller.law_params.eps=nan"),
    ("sontag eps str", lambda f: make_law("sontag", f.clf.lyap, -5, 5, eps="a"), ConfigError,
     "controller.law_params.eps='a': expected a number"),
    ("lie_gain k True", lambda f: make_law("lie_gain", f.clf.lyap, -5, 5, k=True), ConfigError,
     "controller.law_params.k=True: expected a number"),
    ("model_lqr weights str", lambda f: make_law("model_lqr", f.clf.lyap, -5, 5, model=f.model, weights="ab"),
     ConfigError, "weights='ab': give (q_x, r_u)"),
    ("law lyap None", lambda f: make_law("sontag", None, -5, 5), ConfigError, "lyap=NoneType: pass the CLF's V"),
    ("synthesize eps str", lambda f: synthesize_clf(f.model, ClfConfig(), law_params={"eps": "a"}), ConfigError,
     "controller.law_params.eps='a'"),
    # -- ClfConfig
    ("region reversed", lambda f: ClfConfig(region_low=1.0, region_high=-1.0), ConfigError,
     "clf.region_low=1.0, clf.region_high=-1.0: need region_low < region_high"),
    ("region str", lambda f: ClfConfig(region_low="a"), ConfigError, "clf.region_low='a': give a finite number"),
    ("region nan", lambda f: ClfConfig(region_low=nan), ConfigError, "clf.region_low=nan"),
    ("region inf", lambda f: ClfConfig(region_high=inf), ConfigError, "clf.region_high=inf"),
    ("region lengths differ", lambda f: ClfConfig(region_low=(-1, -1), region_high=(1,)), ConfigError,
     "give both with one number per state"),
    ("region n=3 for n=2", lambda f: synthesize_clf(f.model, ClfConfig(region_low=(-1, -1, -1))), ConfigError,
     "clf.region_low=(-1, -1, -1) has 3 value(s); the model has n=2 state(s)"),
    ("accept_inaccurate 'no'", lambda f: ClfConfig(accept_inaccurate="no"), ConfigError,
     "clf.accept_inaccurate='no': use true or false"),
    ("q_x inf", lambda f: ClfConfig(q_x=inf), ConfigError, "clf.q_x=inf: use a finite weight"),
    ("eps 1e300", lambda f: ClfConfig(eps=1e300), ConfigError, "clf.eps=1e+300: use a small fraction in (0, 1]"),
    ("eps inf lqr_x", lambda f: synthesize_clf(f.model, ClfConfig(method="lqr_x", eps=inf)), ConfigError,
     "clf.eps=inf"),
    ("grid 1e5", lambda f: synthesize_clf(f.model, ClfConfig(grid=10 ** 5)), ConfigError,
     "clf.grid=100000 samples 1e+10 states for n=2"),
    ("c_upper 1e300", lambda f: synthesize_clf(f.model, ClfConfig(c_upper=1e300)), ClfError,
     "bounds this large or this far apart"),
    ("synthesize config None", lambda f: synthesize_clf(f.model, None), ConfigError, "config=None: pass a ClfConfig"),
    # -- P, load_clf
    ("clf_from_P str", lambda f: clf_from_P(f.model, "abc"), ConfigError, "P='abc': give a (9, 9) matrix"),
    ("clf_from_P nan", lambda f: clf_from_P(f.model, np.full((9, 9), nan)), ConfigError, "non-finite entries"),
    ("clf_from_P asymmetric", lambda f: clf_from_P(f.model, np.eye(9) + np.triu(np.ones((9, 9)), 1)), ConfigError,
     "P is not symmetric"),
    ("load_clf missing", lambda f: load_clf(f.tmp / "nope.npz", f.model, ClfConfig()), ConfigError,
     "nope.npz' does not exist: give the .npz save_clf wrote"),
    ("load_clf model file", lambda f: load_clf(f.tmp / "model.npz", f.model, ClfConfig()), ConfigError,
     "model.npz' is not a CLF file written by save_clf"),
    ("load_clf config None", lambda f: load_clf(f.tmp / "model.npz", f.model, None), ConfigError,
     "load_clf: config=None: pass the ClfConfig"),
]


@pytest.mark.parametrize("call,error,fragment", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_refused_in_one_line(fx, call, error, fragment):
    with pytest.raises(error) as info:
        call(fx)
    msg = str(info.value)
    assert "\n" not in msg
    assert fragment in msg


def test_a_law_on_other_bounds_warns(fx):
    """The LMPC's (21f) asks for the law's decrease: a law on wider bounds than the LMPC's makes the QP infeasible
    wherever h leaves them.  Narrower LMPC bounds are a test's tool (a (21e) slack), so this warns, not refuses."""
    with pytest.warns(UserWarning, match=r"the law's bounds \[-5.0\]..\[5.0\] differ from the controller's"):
        lmpc(fx, lo=-0.01, hi=0.01)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        lmpc(fx)                                      # the same bounds: silent


def test_valid_blocking_is_unchanged():
    assert block_sizes(100, 5, 20).tolist() == [1, 1, 1, 1, 1, 1, 2, 2, 2, 3, 4, 4, 5, 5, 7, 8, 10, 12, 14, 16]
    assert block_sizes(20, 2, 5).tolist() == [1, 1, 1, 4, 13]
    assert block_sizes(10, None, None).tolist() == [1] * 10
    assert block_sizes(10, 5, 1000).tolist() == [1] * 10   # blocks >= horizon: no blocking, as before


def test_save_clf_makes_folders_and_load_clf_reads_it_back(fx):
    path = fx.tmp / "new" / "deeper" / "clf.npz"
    save_clf(fx.clf, path)
    back = load_clf(path, fx.model, fx.clf.config)
    assert np.array_equal(back.P, fx.clf.P) and back.r == fx.clf.r and back.r_hat == fx.clf.r_hat


def test_other_controllers_share_the_bounds_check(fx):
    pytest.importorskip("casadi")
    from kexp.control.bilinear_nlp import IpoptLmpc
    from kexp.control.oracle import NmpcOracle
    with pytest.raises(ConfigError, match="controller.u_min=5.0, controller.u_max=-5.0: need finite u_min < u_max"):
        NmpcOracle(fx.s, None, 5.0, -5.0)
    with pytest.raises(ConfigError, match="the CLF is on k=5"):
        IpoptLmpc(fx.model, fx.clf5, fx.h, dataclasses.replace(SMALL, horizon=3, free_moves=None, blocks=None), -5, 5)
