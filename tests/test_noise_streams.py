"""Independent noise streams (issue 32): the data's noise, the closed loop's measurement noise and its input
disturbance each draw from their own stream of their seed (kexp.data.noise.noise_rng), so with equal seeds (all
default to 0) they are independent; the same seed still gives the same draws run to run."""
import numpy as np
import pytest

from kexp.control import LqrController
from kexp.data import Circle, DataConfig, collect
from kexp.data.noise import DATA_NOISE, DISTURBANCE, MEASUREMENT_NOISE, add_measurement_noise, noise_rng
from kexp.errors import ConfigError
from kexp.simulate import Disturbance, SimConfig, closed_loop
from kexp.simulate.closed_loop import NoiseConfig
from kexp.systems import make_system

VDP = make_system("vanderpol")


@pytest.fixture(scope="module")
def clean():
    # 40 trajectories × 301 samples × 2 states = 24 080 noise samples
    return collect(VDP, Circle(n_traj=40, radius=2.5), DataConfig(T=3.0))


def _corr(a, b):
    return float(np.corrcoef(np.ravel(a), np.ravel(b))[0, 1])


def test_equal_seeds_give_uncorrelated_streams_for_each_purpose(clean):
    """Seed 0 for all: the data noise as the data set gets it (its whole (n_traj, T+1, n) draw) against the first
    as many draws of the measurement noise and of the disturbance: sample correlations within 4/sqrt(N) of 0
    (before issue 32 the first two were the same numbers: correlation 1)."""
    e = (add_measurement_noise(clean, 1.0, relative=False, seed=0).x - clean.x)
    n_samples = e.size
    assert n_samples >= 10_000
    v = noise_rng(0, MEASUREMENT_NOISE).standard_normal(n_samples)
    w = noise_rng(0, DISTURBANCE).standard_normal(n_samples)
    bound = 4 / np.sqrt(n_samples)
    for a, b in ((e, v), (e, w), (v, w)):
        assert abs(_corr(a, b)) < bound
        assert not np.isclose(np.ravel(a)[:100], np.ravel(b)[:100]).any()
    # each stream is what the purpose's generator draws, and the same every time
    # (x + e) − x is e to the rounding of x (|x| < 4: 1e-15)
    np.testing.assert_allclose(np.ravel(e), noise_rng(0, DATA_NOISE).standard_normal(n_samples), rtol=0, atol=1e-14)
    np.testing.assert_array_equal(v, noise_rng(0, MEASUREMENT_NOISE).standard_normal(n_samples))
    assert abs(_corr(e, np.random.default_rng(0).standard_normal(n_samples))) < bound   # not default_rng(seed)


def test_the_closed_loops_noise_is_not_the_data_noise_of_trajectory_0(clean):
    """The reported case: data noise and closed-loop measurement noise both at seed 0 (absolute σ, equal for both):
    v_k is not trajectory 0's data noise at sample k; the disturbance w_k (seed 0) is neither; a second run draws
    exactly the same v and w."""
    sigma = 0.05
    data_noise = (add_measurement_noise(clean, sigma, relative=False, seed=0).x - clean.x)[0]   # (T+1, n)
    cfg = SimConfig(T=1.0, noise=NoiseConfig(std=sigma, relative=False, seed=0),
                    disturbance=Disturbance(std=sigma, seed=0))

    def go():
        res = closed_loop(VDP, LqrController(VDP, -5, 5), [0.5, -0.5], cfg)
        return (np.array([r.x_meas for r in res.records]) - res.x[:-1], np.array([r.w for r in res.records]))

    v, w = go()
    steps = v.shape[0]
    assert steps == 100
    assert not np.isclose(v, data_noise[:steps], rtol=0, atol=1e-12).any()
    assert not np.isclose(w[:, 0], v[:, 0], rtol=0, atol=1e-12).any()
    assert not np.isclose(w[:, 0], data_noise[:steps, 0], rtol=0, atol=1e-12).any()
    np.testing.assert_allclose(v, sigma * noise_rng(0, MEASUREMENT_NOISE).standard_normal((steps, 2)), atol=1e-15)
    v2, w2 = go()
    assert np.array_equal(v, v2) and np.array_equal(w, w2)


def test_a_stream_depends_on_its_seed_and_purpose_only():
    draw = lambda seed, purpose: noise_rng(seed, purpose).standard_normal(8)  # noqa: E731
    assert np.array_equal(draw(3, DATA_NOISE), draw(3, DATA_NOISE))
    outs = [draw(s, p) for s in (0, 1) for p in (DATA_NOISE, MEASUREMENT_NOISE, DISTURBANCE)]
    assert len({o.tobytes() for o in outs}) == 6
    with pytest.raises(ConfigError, match=r"sim\.noise\.seed=-1: use an int >= 0"):
        noise_rng(-1, MEASUREMENT_NOISE)


def test_per_x0_noise_draws_differ_by_x0_and_repeat():
    """sim.noise.per_x0: each initial condition draws its own measurement noise (the x0's bits join the stream's
    key), the same x0 the same draw; without it every x0 of a sweep measures one draw (issue 32's finding)."""
    sigma = 0.05

    def noise(x0, per_x0):
        cfg = SimConfig(T=0.3, noise=NoiseConfig(std=sigma, relative=False, seed=0, per_x0=per_x0))
        res = closed_loop(VDP, LqrController(VDP, -5, 5), x0, cfg)
        return np.array([r.x_meas for r in res.records]) - res.x[:-1]

    a, b = noise([0.5, -0.5], True), noise([0.5, -0.4], True)
    assert np.array_equal(a, noise([0.5, -0.5], True))             # reproducible from the config alone
    assert abs(_corr(a, b)) < 0.5 and not np.isclose(a, b).any()     # another x0: another draw
    shared = noise([0.5, -0.5], False)
    np.testing.assert_allclose(shared, noise([0.5, -0.4], False), rtol=0, atol=1e-12)   # one draw for all x0
    # the per-x0 stream is noise_rng with the x0's float64 bits in its key
    key = np.array([0.5, -0.5]).view(np.uint64)
    ref = np.random.default_rng(np.random.SeedSequence(0, spawn_key=(2, *map(int, key)))).standard_normal(a.size)
    np.testing.assert_allclose(np.ravel(a), sigma * ref, rtol=0, atol=1e-12)
    with pytest.raises(ConfigError, match="per_x0"):
        NoiseConfig(per_x0="yes")
