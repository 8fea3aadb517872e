"""Data from files (issue 12, item 1): recorded runs (NPZ, CSV, kexp's run.mcap) -> Dataset, and back."""
import subprocess
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg as sla

from kexp.data import Circle, DataConfig, Excitation, RegionFilter, collect, read_runs, write_runs
from kexp.dictionary import Monomials
from kexp.errors import DataError
from kexp.identify import IdentifyConfig, identify
from kexp.recording import read_log
from kexp.systems import make_system
from cli import console_script

ROOT = Path(__file__).resolve().parents[1]
VDP = make_system("vanderpol", {})


@pytest.fixture(scope="module")
def small():
    # a mask filter leaves masked samples inside runs: they travel as NaN rows and come back masked
    return collect(VDP, Circle(8, 2.0), DataConfig(T=2.0, filter=RegionFilter(low=-2.2, high=2.2)))


@pytest.mark.parametrize("fmt", ["npz", "csv"])
def test_round_trip_gives_the_same_model(small, fmt, tmp_path):
    assert (~small.valid).sum() > 0  # the filter masked some samples
    paths = write_runs(small, tmp_path, fmt)
    assert len(paths) == 8 and all(p.suffix == f".{fmt}" for p in paths)
    back = read_runs(tmp_path, n=2, m=1, dt=0.01, system_name="vanderpol")
    # trailing masked samples are not written: compare on the common length, the rest is masked padding
    T1 = back.x.shape[1]
    assert np.array_equal(back.valid, small.valid[:, :T1]) and not small.valid[:, T1:].any()
    assert np.array_equal(back.x[back.valid], small.x[:, :T1][small.valid[:, :T1]])
    assert back.u is None and back.n_pairs == small.n_pairs
    assert back.report.n_nan_samples + back.report.n_padded_samples == back.report.n_masked_samples
    cfg = IdentifyConfig()
    a, b = identify(VDP, small, Monomials(2, 3), cfg), identify(VDP, back, Monomials(2, 3), cfg)
    for name in ("Lambda", "B", "b", "C"):
        assert np.allclose(getattr(a, name), getattr(b, name), rtol=0, atol=1e-12), name
    assert np.max(np.abs(a.eigenvalues - b.eigenvalues)) < 1e-12


@pytest.mark.parametrize("fmt", ["npz", "csv"])
def test_forced_round_trip_gives_the_same_regressed_model(fmt, tmp_path):
    """Inputs travel too: PRBS on half the runs (the others u = 0), B and b regressed from the data."""
    ds = collect(VDP, Circle(8, 2.0), DataConfig(T=2.0, excitation=Excitation(kind="prbs", hold=5, fraction=0.5)))
    write_runs(ds, tmp_path, fmt)
    back = read_runs(tmp_path, n=2, m=1, dt=0.01)
    assert np.array_equal(back.u, ds.u) and int(np.any(back.u != 0, axis=(1, 2)).sum()) == 4
    cfg = IdentifyConfig(inputs="regression")
    a, b = identify(VDP, ds, Monomials(2, 3), cfg), identify(VDP, back, Monomials(2, 3), cfg)
    for name in ("Lambda", "B", "b", "C"):
        assert np.allclose(getattr(a, name), getattr(b, name), rtol=0, atol=1e-12), name


def test_runs_of_different_lengths_are_padded_and_masked(tmp_path):
    rng = np.random.default_rng(0)
    lengths = [5, 12, 8]
    xs, u1 = [], None
    for i, L in enumerate(lengths):
        xs.append(rng.normal(size=(L, 2)))
        if i == 1:
            u1 = rng.normal(size=(L - 1, 1))
        np.savez(tmp_path / f"r{i}.npz", t=1.0 + np.arange(L) * 0.1, x=xs[i], **({"u": u1} if i == 1 else {}))
    ds = read_runs(tmp_path, n=2, m=1, dt=0.1)
    for i, L in enumerate(lengths):         # the values written come back, bit for bit, then masked padding
        assert np.array_equal(ds.x[i, :L], xs[i]) and ds.valid[i, :L].all() and not ds.valid[i, L:].any()
    assert np.array_equal(ds.u[1], u1)
    assert ds.x.shape == (3, 12, 2) and ds.u.shape == (3, 11, 1)
    assert ds.valid.sum(axis=1).tolist() == lengths
    assert ds.n_pairs == sum(L - 1 for L in lengths) == 22
    assert ds.report.n_padded_samples == 7 + 0 + 4 and ds.report.n_nan_samples == 0
    assert np.all(ds.u[0] == 0) and np.all(ds.u[2] == 0) and ds.forced  # runs without u: u = 0
    assert np.allclose(ds.t, np.arange(12) * 0.1)  # each run's time relative to its first sample


def test_region_filter_applies_to_recorded_runs(tmp_path):
    x = np.column_stack([np.linspace(-1, 1, 21), np.zeros(21)])  # x1 from -1 to 1 in steps of 0.1
    np.savez(tmp_path / "a.npz", t=np.arange(21) * 0.01, x=x)
    ds = read_runs(tmp_path, n=2, m=1, dt=0.01, region_filter=RegionFilter(low=-0.45, high=0.45), x_eq=[0.0, 0.0])
    assert ds.valid[0].sum() == 9 and ds.report.n_masked_samples == 12 and ds.report.filter == "mask"
    assert ds.n_pairs == 8
    with pytest.raises(DataError, match="the filter removed every sample"):  # mode drop: the run leaves it
        read_runs(tmp_path, n=2, m=1, dt=0.01, x_eq=[0.0, 0.0],
                  region_filter=RegionFilter(low=-0.45, high=0.45, mode="drop"))


def test_a_dropped_run_s_padding_is_not_counted(tmp_path):
    """Runs of 5, 12 and 8 samples, the 8-sample one leaving the region (mode drop): the two kept are padded to
    12 (the longest file's length) and only their padding counts, so the report's padding is part of its masked
    samples and both are the kept data's masked samples."""
    x = {5: np.zeros((5, 2)), 12: np.zeros((12, 2)), 8: np.c_[np.linspace(0, 2, 8), np.zeros(8)]}
    for L, xs in x.items():
        np.savez(tmp_path / f"r{L:02d}.npz", t=np.arange(L) * 0.1, x=xs)
    ds = read_runs(tmp_path, n=2, m=1, dt=0.1, region_filter=RegionFilter(high=1.0, mode="drop"))
    r = ds.report
    assert r.n_dropped_traj == 1 and ds.x.shape == (2, 12, 2)
    assert r.n_padded_samples == 7 == r.n_masked_samples == int((~ds.valid).sum())


def test_nan_rows_are_masked_and_counted(tmp_path):
    x = np.column_stack([np.linspace(0, 1, 11), np.linspace(1, 2, 11)])
    x[3, 1] = np.nan
    x[7] = np.nan
    u = np.zeros((10, 1))
    u[9, 0] = np.nan  # the input of the last pair
    np.savez(tmp_path / "a.npz", t=np.arange(11) * 0.01, x=x, u=u)
    ds = read_runs(tmp_path / "a.npz", n=2, m=1, dt=0.01)
    assert np.flatnonzero(~ds.valid[0]).tolist() == [3, 7, 9]
    assert ds.report.n_nan_samples == 3 and ds.report.n_masked_samples == 3
    assert ds.n_pairs == 10 - 6  # pairs 2,3 / 6,7 / 8,9 lose a sample
    assert "3 NaN row(s) masked" in ds.report.lines()[0]
    assert np.all(np.isfinite(ds.u))


def test_mcap_log_of_a_kexp_run_is_data():
    path = ROOT / "recordings" / "paper_vanderpol.mcap"
    steps = read_log(path).messages("/step")
    ds = read_runs(path, n=2, m=1, dt=0.01, system_name="vanderpol")
    assert ds.x.shape == (1, len(steps), 2) == (1, 200, 2) and ds.u.shape == (1, 199, 1)
    assert np.array_equal(ds.x[0], [s["x"] for s in steps])
    assert np.array_equal(ds.u[0, :, 0], [s["u"][0] for s in steps[:-1]])
    assert ds.forced and ds.n_pairs == 199 and ds.report.source.startswith("1 mcap file(s)")
    # closed-loop data identifies a model (B, b regressed from the logged inputs)
    model = identify(VDP, ds, Monomials(2, 2), IdentifyConfig(inputs="regression", holdout=0))
    assert model.k == 6 and model.report["n_pairs_train"] == 199
    assert np.all(np.isfinite(model.B)) and np.all(np.isfinite(model.b))
    # closed-loop u is nearly a function of x, so the regressors [u^p φ(x)], p = 0..degree (φ = 1, x1, x2, x1², x1x2,
    # x2², written out here) are nearly collinear: condition number 6e5 with degree 1, ~1e13 with degree 3.  With
    # degree 1 the drift's eigenvalues are those of logm(K̄0)/Δ from numpy's least squares to 1e-7 (cond·eps; measured
    # 2e-11; that model drops the constant's eigenvalue 0).  With degree 3 the coefficients are not determined (their
    # poorly determined directions moved eigenvalues by O(1) when the golden's inputs changed by 1e-6), so the fit is
    # compared by what it predicts: φ(x⁺) from kexp's streamed regression against numpy's, on the logged pairs
    x, u = ds.x[0], ds.u[0, :, 0]

    def phi(x):
        return np.column_stack([np.ones(len(x)), x[:, 0], x[:, 1], x[:, 0] ** 2, x[:, 0] * x[:, 1], x[:, 1] ** 2])

    def regressors(degree):
        return np.hstack([phi(x[:-1]) * u[:, None] ** p for p in range(degree + 1)])
    fitted = identify(VDP, ds, Monomials(2, 2), IdentifyConfig(inputs="regression", holdout=0, input_degree=1))
    coef = np.linalg.lstsq(regressors(1), phi(x[1:]), rcond=None)[0]
    ref = np.linalg.eigvals(sla.logm(coef[:6].T)) / 0.01
    dist = np.abs(fitted.eigenvalues[:, None] - ref[None, :])
    assert dist.min(axis=1).max() < 1e-7, (fitted.eigenvalues, ref)              # each is the reference's
    unmatched = ref[dist.min(axis=0) >= 1e-7]                                      # the constant's 0
    assert len(unmatched) == 1 and np.all(np.abs(unmatched) < 1e-9)
    from kexp.identify.regression import fit_bilinear
    fit3 = fit_bilinear(ds.iter_pairs(1000, with_inputs=True), Monomials(2, 2).lift, m=1, degree=3)
    reg3 = regressors(3)
    ours = np.hstack([phi(x[:-1])] + [phi(x[:-1]) * u[:, None] ** p for p in (1, 2, 3)]) @ fit3.coef
    theirs = reg3 @ np.linalg.lstsq(reg3, phi(x[1:]), rcond=None)[0]
    # both are least-squares fits of the same targets: the fitted values agree to what the residual allows
    assert np.linalg.norm(ours - theirs) <= 1e-6 * np.linalg.norm(phi(x[1:]))
    with pytest.raises(DataError, match="recorded with system 'vanderpol', but system.name='pendulum'"):
        read_runs(path, n=2, m=1, dt=0.01, system_name="pendulum")


def test_a_cut_mcap_log_gives_its_steps_and_says_so(tmp_path):
    data = (ROOT / "recordings" / "paper_vanderpol.mcap").read_bytes()
    cut = tmp_path / "run.mcap"
    cut.write_bytes(data[:int(0.6 * len(data))])
    ds = read_runs(cut, n=2, m=1, dt=0.01)
    full = read_runs(ROOT / "recordings" / "paper_vanderpol.mcap", n=2, m=1, dt=0.01)
    T1 = ds.x.shape[1]
    assert 2 <= T1 < 200 and np.array_equal(ds.x[0], full.x[0, :T1])
    assert "1 log(s) cut short or unfinished: run.mcap is truncated" in ds.report.lines()[0]


def test_reading_streams_one_file_at_a_time(tmp_path):
    """Memory beyond the Dataset: the reader allocates the Dataset's arrays once and fills them file by file;
    stacking the runs instead (list of arrays, then np.stack, then the Dataset's copy) peaks at about 3× x."""
    ds = collect(VDP, Circle(40, 2.0), DataConfig(T=20.0))
    write_runs(ds, tmp_path, "npz")
    x_bytes = ds.x.nbytes  # 40 × 2001 × 2 floats = 1.28 MB
    tracemalloc.start()
    back = read_runs(tmp_path, n=2, m=1, dt=0.01)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert back.x.nbytes == x_bytes
    # x allocated once + the Dataset's own read-only copy + masks + one file: measured 2.39× (stacking: 3.19×)
    assert peak < 2.7 * x_bytes, peak / x_bytes


def test_ragged_csv_row_and_digest(tmp_path):
    _csv(tmp_path / "a.csv", ["t", "x1", "x2"], [[0.0, 1.0, 2.0], [0.01, 1.0], [0.02, 1.0, 2.0]])
    with pytest.raises(DataError, match="data row 2 has 2 cells, the header 3"):
        read_runs(tmp_path, n=2, m=1, dt=0.01)
    # the digest (part of the model cache key) follows the files' content, not only their path
    _csv(tmp_path / "a.csv", ["t", "x1", "x2"], [[0.0, 1.0, 2.0], [0.01, 1.0, 2.5], [0.02, 1.0, 2.0]])
    d1 = read_runs(tmp_path, n=2, m=1, dt=0.01).report.digest
    _csv(tmp_path / "a.csv", ["t", "x1", "x2"], [[0.0, 1.0, 2.0], [0.01, 1.0, 2.6], [0.02, 1.0, 2.0]])
    d2 = read_runs(tmp_path, n=2, m=1, dt=0.01).report.digest
    assert len(d1) == 20 and d1 != d2


def _csv(path, header, rows):
    path.write_text(",".join(header) + "\n" + "\n".join(",".join(map(str, r)) for r in rows) + "\n")


def _good_rows(L=30, dt=0.01):
    return [[k * dt, 0.5 + 0.01 * k, -0.5] for k in range(L)]


def _npz_run(path: Path, t, x, u=None):
    np.savez(path, t=t, x=x, **({} if u is None else {"u": u}))


def test_the_sampling_check_is_relative_to_dt(tmp_path):
    """t must step by dt within 1e-6·dt: at dt = 0.01 s a 1e-7 s slip (1e-5·dt) is refused and a 5e-9 s one
    (5e-7·dt) kept; at dt = 10 s a 5e-6 s slip (5e-7·dt) is kept."""
    x = np.random.default_rng(0).normal(size=(30, 2))
    for dt, slip, ok in ((0.01, 1e-7, False), (0.01, 5e-9, True), (10.0, 5e-6, True)):
        d = tmp_path / f"{dt}_{slip}"
        d.mkdir()
        t = np.arange(30) * dt
        t[10:] += slip
        _npz_run(d / "a.npz", t, x)
        if ok:
            assert read_runs(d, n=2, m=1, dt=dt).valid.all()
        else:
            with pytest.raises(DataError, match=r"irregular or mismatched sampling: t\[10\] - t\[9\]"):
                read_runs(d, n=2, m=1, dt=dt)


def test_a_run_whose_inputs_are_all_zero_is_unforced(tmp_path):
    """A recorded u column of zeros is an unforced run (its windows count for the unforced quality measures);
    streamed and in memory alike."""
    from kexp.data import open_runs
    x, t = np.random.default_rng(1).normal(size=(30, 2)), np.arange(30) * 0.01
    _npz_run(tmp_path / "a.npz", t, x, np.zeros((29, 1)))
    _npz_run(tmp_path / "b.npz", t, x, np.r_[np.zeros((28, 1)), [[0.3]]])
    src, mem = open_runs(tmp_path, n=2, m=1, dt=0.01), read_runs(tmp_path, n=2, m=1, dt=0.01)
    assert src.run_forced().tolist() == mem.run_forced().tolist() == [False, True]
    assert src.forced and mem.forced


def test_an_empty_path_is_refused(tmp_path):
    """'' is not the current folder: a one-line ConfigError naming the argument."""
    from kexp.data import open_runs
    from kexp.errors import ConfigError
    for fn in (read_runs, open_runs):
        with pytest.raises(ConfigError, match=rf"{fn.__name__}: path='': give a path"):
            fn("", n=2, m=1, dt=0.01)


def _bad_files(tmp: Path):
    """(name, path to pass as data.source.path, extra overrides, fragment of the one-line message)."""
    cases = []
    d = tmp / "missing_col"; d.mkdir()
    _csv(d / "a.csv", ["t", "x1"], [[r[0], r[1]] for r in _good_rows()])
    cases.append(("csv missing state column", d, [], "1 state column(s) ['x1'], but the system has n=2"))
    d = tmp / "extra_col"; d.mkdir()
    _csv(d / "a.csv", ["t", "x1", "x2", "speed"], [r + [0] for r in _good_rows()])
    cases.append(("csv extra column", d, [], "extra column(s) ['speed']"))
    d = tmp / "npz_missing"; d.mkdir()
    np.savez(d / "a.npz", t=np.arange(30) * 0.01)
    cases.append(("npz missing x", d, [], "missing array(s) ['x']"))
    d = tmp / "npz_extra"; d.mkdir()
    np.savez(d / "a.npz", t=np.arange(30) * 0.01, x=np.zeros((30, 2)), y=np.zeros(3))
    cases.append(("npz extra array", d, [], "extra array(s) ['y']"))
    d = tmp / "npz_dim"; d.mkdir()
    np.savez(d / "a.npz", t=np.arange(30) * 0.01, x=np.zeros((30, 3)))
    cases.append(("state dimension", d, [], "x has 3 state column(s), but the system has n=2"))
    d = tmp / "irregular"; d.mkdir()
    rows = _good_rows()
    rows[10][0] += 0.004
    _csv(d / "a.csv", ["t", "x1", "x2"], rows)
    cases.append(("irregular t", d, [], "irregular or mismatched sampling: t[10] - t[9] = 0.014"))
    d = tmp / "other_dt"; d.mkdir()
    _csv(d / "a.csv", ["t", "x1", "x2"], _good_rows(dt=0.02))
    cases.append(("dt of the files differs", d, [], "set data.dt=0.02"))
    d = tmp / "few"; d.mkdir()
    _csv(d / "a.csv", ["t", "x1", "x2"], _good_rows(L=12))
    cases.append(("too few pairs", d, [], "recorded data gives 11 usable training pairs"))
    d = tmp / "allnan"; d.mkdir()
    _csv(d / "a.csv", ["t", "x1", "x2"], [[r[0], "nan", "nan"] for r in _good_rows()])
    cases.append(("no finite sample", d, [], "no sample has finite x"))
    cases.append(("path does not exist", tmp / "nope", [], "does not exist"))
    return cases


def test_every_file_error_is_one_line_with_exit_code_2(tmp_path):
    """Through the `kexp` CLI (the schema accepts data.source.*), each in its own process."""
    for i, (name, path, extra, fragment) in enumerate(_bad_files(tmp_path)):
        proc = subprocess.run(   # each case its own run folder: a refused run's summary.json holds that folder
            [console_script("kexp"), "data.source.kind=files", f"data.source.path={path}", "dictionary.degree=3",
             "identification.holdout=0", "sim.allow_outside_data=true", "logging.rrd=false", "logging.progress=false",
             "cache.enabled=false", f"hydra.run.dir={tmp_path / f'out{i}'}", *extra],
            capture_output=True, text=True, timeout=120)
        lines = proc.stderr.strip().splitlines()
        assert proc.returncode == 2, (name, proc.stderr[-2000:])
        assert len(lines) == 1 and "Traceback" not in proc.stderr, (name, proc.stderr[-2000:])
        assert lines[0].startswith("kexp: error: ") and fragment in lines[0], (name, lines[0])
