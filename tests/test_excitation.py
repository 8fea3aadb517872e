"""Forced data (issue 12, item 2): excitation kinds uniform | prbs | multisine, seeded, mixed with unforced runs."""
import numpy as np
import pytest

from kexp.data import Circle, DataConfig, Excitation, collect
from kexp.errors import ConfigError
from kexp.systems import make_system

VDP = make_system("vanderpol", {})


def test_prbs_is_plus_minus_amplitude_and_switches_only_on_hold_boundaries():
    exc = Excitation(kind="prbs", amplitude=2.5, hold=7)
    u = exc.draw(20, 300, 2, np.random.default_rng(3), dt=0.01)
    assert u.shape == (20, 300, 2)
    assert set(np.unique(u).tolist()) == {-2.5, 2.5}
    switches = np.flatnonzero(np.any(u[:, 1:] != u[:, :-1], axis=(0, 2))) + 1
    assert switches.size > 0 and np.all(switches % 7 == 0)
    # a fair coin per block: about half the 43 blocks × 40 (trajectory, input) pairs are +amplitude
    assert abs(np.mean(u[:, ::7] > 0) - 0.5) < 0.05


def test_multisine_is_bounded_and_has_the_requested_frequencies():
    dt, n_steps, freqs = 0.01, 2000, (0.5, 2.0, 5.0)  # 20 s: frequency resolution 0.05 Hz, Nyquist 50 Hz
    exc = Excitation(kind="multisine", amplitude=1.5, frequencies=freqs, hold=1)
    u = exc.draw(4, n_steps, 1, np.random.default_rng(0), dt=dt)
    assert np.max(np.abs(u)) <= 1.5 and np.max(np.abs(u)) > 0.75
    spectrum = np.abs(np.fft.rfft(u[:, :, 0], axis=1))
    f = np.fft.rfftfreq(n_steps, dt)
    for i in range(4):
        peaks = np.sort(f[np.argsort(spectrum[i])[-3:]])
        assert np.allclose(peaks, freqs), peaks
        # each sinusoid has amplitude 1.5/3: its FFT bin is 0.5·(n_steps/2)
        assert np.allclose(spectrum[i][np.isin(f, freqs)], 0.5 * n_steps / 2, rtol=1e-9)


def test_multisine_above_nyquist_is_refused():
    with pytest.raises(ConfigError, match="not below the Nyquist frequency 1/\\(2·hold·dt\\) = 5 Hz"):
        DataConfig(dt=0.01, excitation=Excitation(kind="multisine", frequencies=(1.0, 6.0), hold=10))


@pytest.mark.parametrize("kind", ["uniform", "prbs", "multisine"])
def test_excitation_is_seeded(kind):
    exc = Excitation(kind=kind, hold=3, fraction=0.5)
    a = exc.draw(10, 50, 1, np.random.default_rng(11), dt=0.01)
    b = exc.draw(10, 50, 1, np.random.default_rng(11), dt=0.01)
    c = exc.draw(10, 50, 1, np.random.default_rng(12), dt=0.01)
    assert np.array_equal(a, b) and not np.array_equal(a, c)


@pytest.mark.parametrize("fraction,n_traj,expected", [(0.3, 10, 3), (0.25, 7, 2), (1.0, 5, 5), (0.0, 5, 0),
                                                      (0.66, 9, 6)])
def test_fraction_excites_exactly_round_fraction_times_n_traj(fraction, n_traj, expected):
    u = Excitation(kind="prbs", fraction=fraction).draw(n_traj, 40, 2, np.random.default_rng(0), dt=0.01)
    excited = np.any(u != 0, axis=(1, 2))
    assert excited.sum() == expected == round(fraction * n_traj)
    assert np.all(u[~excited] == 0)


def test_uniform_is_the_default_kind_and_draws_as_before():
    """data.excitation: {low, high, hold} keeps meaning the original uniform excitation, number for number."""
    exc = Excitation(-2.0, 2.0, hold=10)
    assert exc.kind == "uniform"
    u = exc.draw(3, 95, 1, np.random.default_rng([0, 1]), dt=0.01)
    blocks = np.random.default_rng([0, 1]).uniform(-2.0, 2.0, (3, 10, 1))
    assert np.array_equal(u, np.repeat(blocks, 10, axis=1)[:, :95])


def test_collect_mixes_excited_and_unforced_runs():
    cfg = DataConfig(T=0.5, excitation=Excitation(kind="prbs", amplitude=1.0, hold=5, fraction=0.5))
    ds = collect(VDP, Circle(6, 1.0), cfg)
    excited = np.any(ds.u != 0, axis=(1, 2))
    assert ds.u.shape == (6, 50, 1) and excited.sum() == 3 and ds.forced
    assert ds.report.lines()[0] == "simulated, 3 of 6 trajectories excited (prbs)"
    assert np.array_equal(ds.x, collect(VDP, Circle(6, 1.0), cfg).x)


def test_excitation_validation():
    for kwargs, needle in [({"kind": "chirp"}, "kind='chirp'; valid"), ({"amplitude": 0.0}, "amplitude=0.0"),
                           ({"fraction": 1.5}, "fraction=1.5"), ({"frequencies": ()}, "non-empty"),
                           ({"hold": 0}, "hold=0")]:
        with pytest.raises(ConfigError, match=needle.replace("(", "\\(")):
            Excitation(**kwargs)
