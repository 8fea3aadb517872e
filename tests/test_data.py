import numpy as np
import pytest

from kexp.data import Box, Circle, DataConfig, Excitation, Points, RegionFilter, collect, make_sampler
from kexp.errors import ConfigError, DataError
from kexp.systems import Pendulum, VanDerPol


def test_samplers_are_seeded_and_shaped():
    c = Circle(50, 2.5).sample(np.zeros(2), seed=3)
    assert c.shape == (50, 2) and np.allclose(np.linalg.norm(c, axis=1), 2.5)
    assert np.array_equal(c, Circle(50, 2.5).sample(np.zeros(2), seed=3))
    assert not np.array_equal(c, Circle(50, 2.5).sample(np.zeros(2), seed=4))
    b = Box(100, (-1, -2), (1, 2)).sample(np.zeros(2), seed=0)
    assert b.shape == (100, 2) and np.all(np.abs(b) <= [1, 2])
    assert Points(((0.1, 0.2), (0.3, 0.4))).sample(np.zeros(2), 0).shape == (2, 2)
    with pytest.raises(ConfigError, match="unknown sampler"):
        make_sampler("disc", n_traj=3)
    with pytest.raises(ConfigError, match="radius"):
        Circle(3, -1.0)


def test_euler_pairs_are_x_plus_f_dt():
    s = VanDerPol()
    ds = collect(s, Circle(3, 1.0), DataConfig(T=0.5, pairs="euler"))
    X, Y = next(ds.iter_pairs(10 ** 6))
    assert X.shape[0] == 3 * 51
    assert np.allclose(Y, X + 0.01 * s.drift(X), atol=1e-15)


def test_next_pairs_and_chunking_are_consistent():
    ds = collect(VanDerPol(), Circle(5, 1.0), DataConfig(T=1.0))
    full = np.concatenate([x for x, _ in ds.iter_pairs(10 ** 6)])
    for cs in (1, 7, 100, 499, 500):
        chunks = list(ds.iter_pairs(cs))
        assert all(len(x) <= cs for x, _ in chunks)
        assert np.array_equal(np.concatenate([x for x, _ in chunks]), full)
    X, Y = next(ds.iter_pairs(10 ** 6))
    assert np.array_equal(X[1:100], Y[:99])  # consecutive samples of the first trajectory


def test_region_filter_masks_pendulum_swing_overs():
    cfg = DataConfig(T=10.0, filter=RegionFilter(low=(-np.pi, None), high=(np.pi, None)))
    ds = collect(Pendulum(), Box(30, -2.0, 2.0), cfg)
    inside = np.abs(ds.x[..., 0]) <= np.pi
    assert np.array_equal(ds.valid, inside)
    assert ds.report.n_masked_samples == int((~inside).sum()) > 0  # some trajectories swing over the top
    X, Y = next(ds.iter_pairs(10 ** 7))
    assert np.all(np.abs(X[:, 0]) <= np.pi) and np.all(np.abs(Y[:, 0]) <= np.pi)
    dropped = collect(Pendulum(), Box(30, -2.0, 2.0),
                      DataConfig(T=10.0, filter=RegionFilter(low=(-np.pi, None), high=(np.pi, None), mode="drop")))
    n_leave = int((~inside.all(axis=1)).sum())
    assert dropped.report.n_dropped_traj == n_leave and dropped.n_traj == 30 - n_leave


def test_filter_that_removes_everything_is_an_error():
    with pytest.raises(DataError, match="removed every sample"):
        collect(VanDerPol(), Circle(3, 2.0), DataConfig(T=0.1, filter=RegionFilter(low=0.5, high=1.0, mode="drop")))


def test_excitation_input_is_piecewise_constant_and_seeded():
    cfg = DataConfig(T=1.0, excitation=Excitation(-2, 2, hold=10))
    ds = collect(VanDerPol(), Circle(4, 1.0), cfg)
    assert ds.u.shape == (4, 100, 1) and ds.forced
    assert np.all(ds.u[:, :10] == ds.u[:, :1]) and np.all(np.abs(ds.u) <= 2)
    assert np.array_equal(ds.u, collect(VanDerPol(), Circle(4, 1.0), cfg).u)


def test_data_config_validation():
    with pytest.raises(ConfigError, match="dt"):
        DataConfig(dt=0.0)
    with pytest.raises(ConfigError, match="duration"):
        DataConfig(T=0.001, dt=0.01)
    with pytest.raises(ConfigError, match="pairs"):
        DataConfig(pairs="forward")


def test_split_by_trajectory():
    ds = collect(VanDerPol(), Circle(10, 1.0), DataConfig(T=0.2))
    train, test = ds.split(0.2, seed=0)
    assert train.n_traj == 8 and test.n_traj == 2
    rows = {tuple(r[0]) for r in train.x} | {tuple(r[0]) for r in test.x}
    assert len(rows) == 10
    # round(holdout·n) test trajectories, at least one when holdout > 0 and there are two to split; disjoint, sorted
    from kexp.data.runs import split_indices
    for n, holdout, n_test in ((10, 0.2, 2), (10, 0.04, 1), (2, 0.01, 1), (1, 0.5, 0), (10, 0.0, 0), (7, 0.5, 4)):
        tr, te = split_indices(n, holdout, seed=3)
        assert (0 if te is None else len(te)) == n_test, (n, holdout)
        both = np.concatenate([tr, [] if te is None else te])
        assert sorted(both.tolist()) == list(range(n)) and np.all(np.diff(tr) > 0)


@pytest.mark.parametrize("n", [2, 3, 5])
def test_circle_samples_lie_on_the_sphere_around_the_centre(n):
    """Circle(radius) draws states at exactly that distance from the centre (the equilibrium), for n = 2 (angles)
    and n > 2 (normalised Gaussian directions), and spreads them: the mean direction is far from a unit vector."""
    center = np.arange(1.0, n + 1) * np.array([1, -1] * n)[:n]
    x = Circle(200, 0.7).sample(center, 3)
    assert x.shape == (200, n)
    assert np.allclose(np.linalg.norm(x - center, axis=1), 0.7, rtol=1e-14)
    assert np.linalg.norm((x - center).mean(axis=0)) < 0.2 * 0.7
    assert Circle(1, 0.7).contains(x[0], center) and not Circle(1, 0.69).contains(x[0], center)
