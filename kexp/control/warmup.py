"""``kexp-compile`` (or ``python -m kexp.control.warmup``): compile kexp's controller kernels into the per-install
cache now (kexp.control.jit_cache), so that no later run waits for them — e.g. as the last step of an install or a
container build.  With the cache already filled it only loads the kernels (about a second) and says so.

It builds two small LMPCs and runs them a few steps: Van der Pol (one input: the polynomial zero-order-hold path)
and the slow-manifold system with two inputs (the exponential path), which between them call every kernel a run
calls, with the argument types a run passes; and, where casadi is installed, the SQP oracle on Van der Pol (its
kernels and that system's generated dynamics; another system's dynamics compile on its first use, in seconds)."""
from __future__ import annotations

import sys
import time


def warm_up() -> None:
    """Build and step the two controllers (compiling, or loading from the cache, every kernel)."""
    import numpy as np

    from ..clf import ClfConfig, synthesize_clf
    from ..data import Circle, DataConfig, collect
    from ..dictionary import Monomials
    from ..identify import identify
    from ..simulate import SimConfig, closed_loop
    from ..systems import VanDerPol
    from ..systems.library import SlowManifold
    from . import Lmpc, LmpcConfig, make_law
    for system, degree in ((VanDerPol(), 3), (SlowManifold(inputs="both"), 2)):
        model = identify(system, collect(system, Circle(20, 1.0), DataConfig(T=2.0)), Monomials(2, degree))
        clf = synthesize_clf(model, ClfConfig())
        law = make_law("sontag", clf.lyap, -5.0, 5.0)
        for cost in ("x", "z"):
            ctrl = Lmpc(model, clf, law, LmpcConfig(state_cost=cost), -5.0, 5.0)
            closed_loop(system, ctrl, np.array([0.3, -0.2]), SimConfig(T=0.05), model=model, lyap=clf.lyap)
    try:
        import casadi  # noqa: F401
    except ImportError:
        return
    from .sqp_oracle import SqpOracle
    SqpOracle(VanDerPol(), None, horizon_steps=10).step(np.array([0.3, -0.2]))


def main(argv=None) -> None:
    from ..cli import Parser
    Parser(prog="kexp-compile", description="Compile kexp's controller kernels into the per-install cache now, so "
           "that no later run waits for them (about a minute once; a second when the cache is filled).").parse_args(argv)
    from .jit_cache import _state, configure
    where = configure()
    start = time.perf_counter()
    warm_up()
    took = time.perf_counter() - start
    verb = "compiled" if _state["announced"] else "already compiled (loaded from the cache)"
    print(f"kexp: controller kernels {verb} in {took:.1f} s; cache: {where or 'numba default'}", file=sys.stderr)


if __name__ == "__main__":
    main()
