"""Identification from recorded files streams (issue 12's last target): the file-backed source gives the same
model as the in-memory Dataset, and its memory does not grow with the number of pairs."""
import csv
import shutil
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from kexp.data import Circle, DataConfig, Excitation, RegionFilter, collect, open_runs, read_runs, write_runs
from kexp.data.noise import add_measurement_noise, data_rms
from kexp.data.streaming import bounds
from kexp.dictionary import Monomials
from kexp.identify import IdentifyConfig, identify
from kexp.identify.identify import auto_scale
from kexp.systems import make_system

VDP = make_system("vanderpol", {})
KW = dict(n=2, m=1, dt=0.01, system_name="vanderpol", x_eq=VDP.equilibrium)


def _read_independently(path: Path):
    """(x (L, n), NaN rows kept; u (L − 1, m) or None) of a file write_runs wrote, read by numpy's npz reader or the
    csv module — not kexp's loader."""
    if path.suffix == ".npz":
        with np.load(path) as f:
            return f["x"], (f["u"] if "u" in f.files else None)
    with open(path, newline="") as fh:
        head, *body = list(csv.reader(fh))
    xs = [j for j, h in enumerate(head) if h.startswith("x")]
    us = [j for j, h in enumerate(head) if h.startswith("u")]
    assert head[0] == "t" and len(xs) == 2
    x = np.array([[float(r[j]) for j in xs] for r in body])
    return x, (np.array([[float(r[j]) for j in us] for r in body[:-1]]) if us else None)


@pytest.mark.parametrize("fmt", ["npz", "csv"])
@pytest.mark.parametrize("forced", [False, True])
def test_streamed_files_give_the_in_memory_model(fmt, forced, tmp_path):
    """Masked NaN rows, a hold-out split, relative measurement noise: the streamed source and read_runs's Dataset
    give the same statistics, the same noise and the same model (identical here; asserted to 1e-12)."""
    if forced:   # PRBS on half the runs, B and b regressed; compare_projection visits strided training samples
        ds = collect(VDP, Circle(8, 2.0), DataConfig(T=2.0, excitation=Excitation(kind="prbs", hold=5, fraction=0.5)))
        cfg = IdentifyConfig(inputs="regression", compare_projection=True)
    else:        # a mask filter leaves NaN rows inside runs
        ds = collect(VDP, Circle(8, 2.0), DataConfig(T=2.0, filter=RegionFilter(low=-2.2, high=2.2)))
        cfg = IdentifyConfig()
    write_runs(ds, tmp_path, fmt)
    mem, src = read_runs(tmp_path, **KW), open_runs(tmp_path, **KW)
    assert src.report == mem.report and src.n_pairs == mem.n_pairs and src.n_traj == mem.n_traj == 8
    # both read the files through kexp's one loader: each file read here by numpy's npz reader or the csv module
    # holds the collected run's values, and both sources give exactly those
    for i, (f, run) in enumerate(zip(src.files, src.runs())):
        x, u = _read_independently(Path(f))
        L, ok = len(x), np.isfinite(x).all(axis=1)
        assert ok.sum() > 0.5 * L and np.array_equal(ok, ds.valid[i, :L]) and not ds.valid[i, L:].any()
        assert np.array_equal(x[ok], ds.x[i, :L][ok])                  # what was written: the collected run
        assert np.array_equal(run.valid, ok) and np.array_equal(run.x[ok], x[ok])
        assert np.array_equal(mem.valid[i, :L], ok) and np.array_equal(mem.x[i, :L][ok], x[ok])
        if forced:
            assert np.array_equal(u, ds.u[i, :L - 1]) and np.array_equal(run.u, u)
            assert np.array_equal(mem.u[i, :L - 1], u)
        else:
            assert u is None and run.u is None and mem.u is None
    assert np.array_equal(data_rms(src, VDP.equilibrium), data_rms(mem, VDP.equilibrium))
    assert bounds(src) == bounds(mem) and auto_scale(src) == auto_scale(mem)
    mem, src = (add_measurement_noise(d, 0.01, seed=3, x_eq=VDP.equilibrium) for d in (mem, src))
    assert src.report.noise_std == mem.report.noise_std and auto_scale(src) == auto_scale(mem)
    a, b = identify(VDP, mem, Monomials(2, 3), cfg), identify(VDP, src, Monomials(2, 3), cfg)
    for name in ("Lambda", "B", "b", "C", "T"):
        assert np.max(np.abs(getattr(a, name) - getattr(b, name))) <= 1e-12, name
    assert np.max(np.abs(a.eigenvalues - b.eigenvalues)) <= 1e-12
    x = np.random.default_rng(0).uniform(-2, 2, (50, 2))
    assert np.max(np.abs(a.to_state(a.lift(x)) - b.to_state(b.lift(x)))) <= 1e-12
    assert np.max(np.abs(a.free_response(a.lift(x), 50)[-1] - b.free_response(b.lift(x), 50)[-1])) <= 1e-12
    assert a.report["prediction_error"] == b.report["prediction_error"]
    assert a.report["n_pairs_train"] == b.report["n_pairs_train"] and a.report["data"] == b.report["data"]


@pytest.mark.parametrize("pairs,flt", [("euler", RegionFilter(low=-2.0, high=2.0)),
                                       ("next", RegionFilter(low=-2.0, high=2.0, mode="drop"))])
def test_streamed_euler_pairs_and_dropped_runs(pairs, flt, tmp_path):
    """Euler pairs (F evaluated run by run) and the drop filter (8 of 12 runs leave the box) stream the same."""
    write_runs(collect(VDP, Circle(12, 1.0), DataConfig(T=3.0)), tmp_path, "npz")
    kw = dict(KW, pair_rule=pairs, drift=VDP.drift, region_filter=flt)
    mem, src = read_runs(tmp_path, **kw), open_runs(tmp_path, **kw)
    assert src.report == mem.report and src.n_traj == mem.n_traj == (12 if flt.mode == "mask" else 4)
    mem, src = (add_measurement_noise(d, 0.02, seed=1, x_eq=VDP.equilibrium) for d in (mem, src))
    a, b = (identify(VDP, d, Monomials(2, 3), IdentifyConfig(on_invalid="drop")) for d in (mem, src))
    for name in ("Lambda", "B", "b", "C", "eigenvalues"):
        assert np.max(np.abs(getattr(a, name) - getattr(b, name))) <= 1e-12, name


def _peak(fn):
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_memory_does_not_grow_with_the_number_of_pairs(tmp_path):
    """2·10⁴ pairs (20 runs) vs 2·10⁵ (the same runs copied 10×): the streamed identification's tracemalloc peak
    grows < 1.5×, while the in-memory Dataset alone grows about 10×."""
    ds = collect(VDP, Circle(20, 2.0), DataConfig(T=10.0))
    small, big = tmp_path / "small", tmp_path / "big"
    paths = write_runs(ds, small, "npz")
    big.mkdir()
    for c in range(10):
        for p in paths:
            shutil.copy(p, big / f"copy{c}_{p.name}")
    kw = dict(n=2, m=1, dt=0.01)
    fit = {}

    def streamed(folder):
        src = open_runs(folder, **kw)
        # no hold-out: both fits see the same distinct pairs (the quality windows then come from the training runs)
        fit[folder.name] = (src.n_pairs, identify(VDP, src, Monomials(2, 3), IdentifyConfig(holdout=0.0)))

    p_small, p_big = _peak(lambda: streamed(small)), _peak(lambda: streamed(big))
    assert fit["small"][0] == 20_000 and fit["big"][0] == 200_000
    assert p_big < 1.5 * p_small, (p_small / 1e6, p_big / 1e6)
    print(f"streamed peak {p_small / 1e6:.1f} MB -> {p_big / 1e6:.1f} MB ({p_big / p_small:.2f}×)")
    # the same data give the same drift whatever the copies (a sanity check of the big fit)
    assert np.max(np.abs(fit["small"][1].eigenvalues - fit["big"][1].eigenvalues)) < 1e-6
    # the probe sees growth where there is some: reading everything into one Dataset grows with the pairs
    m_small = _peak(lambda: read_runs(small, **kw))
    m_big = _peak(lambda: read_runs(big, **kw))
    assert m_big > 5 * m_small, (m_small / 1e6, m_big / 1e6)
    print(f"in-memory Dataset peak {m_small / 1e6:.1f} MB -> {m_big / 1e6:.1f} MB ({m_big / m_small:.2f}×)")
