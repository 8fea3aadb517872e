import os

# one BLAS thread: deterministic, and fast on the shared 2-core machines
for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import tempfile  # noqa: E402

# the compiled kernels stay in the user's per-install cache (kexp.control.jit_cache: ~/.cache/kexp/numba/<tag>, or
# NUMBA_CACHE_DIR): importing kexp.control exports it as NUMBA_CACHE_DIR before the model cache moves, so that a
# session does not compile them all again
import kexp.control  # noqa: E402,F401
# the model cache of the app goes to a fresh folder per test session, never the user's ~/.cache/kexp
os.environ["KEXP_CACHE_DIR"] = tempfile.mkdtemp(prefix="kexp-cache-")

import numpy as np  # noqa: E402
import pytest  # noqa: E402


@pytest.fixture(scope="session")
def short_lmpc_run():
    """A short LMPC closed loop on Van der Pol (200 steps, degree-3 model, plans every 10 steps), for the logging
    tests: (model, clf, result, [(StepRecord, ControlStep), ...]).  Treat it as read-only (copy the list)."""
    from kexp.clf import ClfConfig, synthesize_clf
    from kexp.control import Lmpc, LmpcConfig, make_law
    from kexp.data import Circle, DataConfig, collect
    from kexp.dictionary import Monomials
    from kexp.identify import identify
    from kexp.simulate import SimConfig, closed_loop
    from kexp.systems import VanDerPol
    system = VanDerPol()
    model = identify(system, collect(system, Circle(30, 2.5), DataConfig(T=3.0)), Monomials(2, 3))
    clf = synthesize_clf(model, ClfConfig())
    law = make_law("sontag", clf.lyap, -5.0, 5.0)
    ctrl = Lmpc(model, clf, law, LmpcConfig(horizon=20, blocks=None), -5.0, 5.0, prediction_every=10)
    steps = []
    result = closed_loop(system, ctrl, np.array([0.4, -0.3]), SimConfig(T=2.0), model=model, lyap=clf.lyap,
                         on_step=lambda rec, st: steps.append((rec, st)))
    return model, clf, result, steps
