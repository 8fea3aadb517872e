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

from ..data import collect
from ..errors import KexpError
from ..identify import identify
from .build import build_data, build_dictionary, build_identification, build_system


def run(cfg: Any, out_dir: str | Path = ".", *, echo=print) -> dict:
    """Run the experiment described by ``cfg`` (a mapping or DictConfig); write its files into ``out_dir``;
    return the metrics.  Until the control stages exist this collects data, identifies the model, saves it
    as ``model.npz`` and prints its summary."""
    out_dir = Path(out_dir)
    t0 = time.perf_counter()
    system = build_system(cfg["system"])
    sampler, data_cfg = build_data(cfg["data"])
    ident_cfg = build_identification(cfg["identification"])
    dataset = collect(system, sampler, data_cfg)
    dictionary = build_dictionary(cfg["dictionary"], system.n, dataset)
    model = identify(system, dataset, dictionary, ident_cfg)
    path = model.save(out_dir / "model.npz")
    echo(model.summary())
    metrics = {
        "status": "identified",
        "system": system.name,
        "k": model.k,
        "cond_phi_x": model.report["cond_phi_x"],
        "prediction_error": model.report["prediction_error"],
        "input_projection_residual": model.report["input_projection_residual"],
        "eigenvalues": [[float(v.real), float(v.imag)] for v in model.eigenvalues],
        "wall_time_s": time.perf_counter() - t0,
        "model": str(path),
    }
    (out_dir / "summary.json").write_text(json.dumps(metrics, indent=2, default=float))
    echo(f"model saved to {path}")
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
