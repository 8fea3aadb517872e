"""The ``kexp`` command: a thin Hydra main around :func:`run`."""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

import hydra
import numpy as np
from omegaconf import DictConfig
from threadpoolctl import threadpool_limits

from ..data import collect
from ..errors import KexpError
from ..identify import identify
from ..simulate import closed_loop
from .build import (build_clf, build_controller, build_data, build_dictionary, build_identification, build_sim,
                    build_system)


def run(cfg: Any, out_dir: str | Path = ".", *, echo=print) -> dict:
    """Run the experiment described by ``cfg`` (a mapping or DictConfig) and write its files into ``out_dir``:
    data → identification → CLF → controller → closed loop on the true system from ``sim.x0``.  Returns the
    metrics (also written to ``summary.json``)."""
    out_dir = Path(out_dir)
    t0 = time.perf_counter()
    # every config section is validated before the long computations start
    system = build_system(cfg["system"])
    sampler, data_cfg = build_data(cfg["data"])
    ident_cfg = build_identification(cfg["identification"])
    clf_cfg = build_clf(cfg["clf"])
    sim_cfg, x0, open_loop = build_sim(cfg["sim"], system, data_cfg.dt)
    build_dictionary(cfg["dictionary"], system.n, None) if cfg["dictionary"].get("scale") != "auto" else None
    dataset = collect(system, sampler, data_cfg)
    dictionary = build_dictionary(cfg["dictionary"], system.n, dataset)
    model = identify(system, dataset, dictionary, ident_cfg)
    model_path = model.save(out_dir / "model.npz")
    echo(model.summary())
    controller, clf = build_controller(cfg["controller"], system, model, clf_cfg)
    echo(clf.summary())
    with threadpool_limits(limits=1):  # BLAS threads on tiny products cost 10-100× (design §2.11)
        result = closed_loop(system, controller, x0, sim_cfg, model=model, lyap=clf.lyap, open_loop=open_loop)
    m = result.metrics
    metrics = {
        "status": result.status,
        "message": result.message,
        "system": system.name,
        "controller": getattr(controller, "name", type(controller).__name__),
        "x0": x0.tolist(),
        "metrics": m.to_dict(),
        "model": {"k": model.k, "cond_phi_x": model.report["cond_phi_x"],
                  "prediction_error": model.report["prediction_error"],
                  "input_projection_residual": model.report["input_projection_residual"],
                  "eigenvalues": [[float(v.real), float(v.imag)] for v in model.eigenvalues]},
        "clf": {"status": clf.status, "r": clf.r, "r_hat": clf.r_hat, "certificate": clf.certificate.to_dict()},
        "wall_time_s": time.perf_counter() - t0,
        "files": {"model": str(model_path)},
    }
    (out_dir / "summary.json").write_text(json.dumps(metrics, indent=2, default=float))
    echo(f"result: {'SUCCESS' if m.success else 'FAILED'} ({result.status}) — ‖x(T)‖ = {m.final_error:.2e}, "
         f"cost J = {m.cost:.4f}, settling {m.settling_time:.2f} s, max|u| = {m.max_abs_u:.3f}, "
         f"fallbacks {m.fallbacks}")
    echo(f"solve time per step: median {m.solve_time_median * 1e3:.2f} ms, p99 {m.solve_time_p99 * 1e3:.2f} ms, "
         f"max {m.solve_time_max * 1e3:.2f} ms")
    echo(f"files: {out_dir.resolve()}")
    return metrics


# conf/ lives at the top of the repository (the package is installed in editable mode, see README)
CONF_DIR = str(Path(__file__).resolve().parents[2] / "conf")


@hydra.main(config_path=CONF_DIR, config_name="config", version_base="1.3")
def _hydra_main(cfg: DictConfig) -> None:
    from hydra.core.hydra_config import HydraConfig
    try:
        run(cfg, HydraConfig.get().runtime.output_dir)
    except KexpError as exc:  # bad input: one line, exit code 2, no traceback
        print(f"kexp: error: {exc}", file=sys.stderr)
        sys.exit(2)


def main() -> None:
    _hydra_main()


if __name__ == "__main__":
    np.set_printoptions(precision=4)
    main()
