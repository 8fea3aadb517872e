"""kexp.data refuses bad arguments at construction (or at the call) with one line naming the field, the bad value
and what to fix: a ConfigError (DataError for bad data), never a numpy/TypeError/AttributeError traceback later
nor a bad value accepted silently.  Valid input gives the same bits as before."""
from types import SimpleNamespace

import numpy as np
import pytest

from kexp.data import (Box, Circle, DataConfig, DataSource, Dataset, Excitation, IntegratorOptions, Points,
                       RegionFilter, collect, integrate, open_runs, read_runs, write_runs)
from kexp.data.noise import add_measurement_noise, data_rms
from kexp.errors import ConfigError, DataError
from kexp.systems import VanDerPol

nan, inf = float("nan"), float("inf")
VDP = VanDerPol()


@pytest.fixture(scope="module")
def ds():
    return collect(VDP, Circle(4, 1.0), DataConfig(T=0.2))


@pytest.fixture(scope="module")
def runs(ds, tmp_path_factory):
    folder = tmp_path_factory.mktemp("runs")
    write_runs(ds, folder)
    return folder


def short(**kw):
    return collect(VDP, Circle(3, 1.0), DataConfig(T=0.1, **kw))


# (label, call, fragment of the one-line message); calls needing the fixtures take (ds, runs)
CONFIG = [
    ("Circle radius str", lambda: Circle(3, "2"), "data.sampler.radius='2': expected a number"),
    ("Circle radius None", lambda: Circle(3, None), "data.sampler.radius=None: expected a number"),
    ("Circle radius list", lambda: Circle(3, [1, 2]), "data.sampler.radius=[1, 2]: expected a number"),
    ("Circle radius bool", lambda: Circle(3, True), "data.sampler.radius=True: expected a number"),
    ("Circle n_traj bool", lambda: Circle(True, 1.0), "data.sampler.n_traj=True: use an int >= 1"),
    ("Circle even str", lambda: Circle(3, 1.0, even="yes"), "data.sampler.even='yes': expected true or false"),
    ("Circle even n=3", lambda: Circle(3, 1.0, even=True).sample(np.zeros(3), 0), "(n = 2 only), but the system "
                                                                                   "has n=3: set even=false"),
    ("Circle huge collect", lambda: collect(VDP, Circle(10 ** 12, 1.0), DataConfig(T=0.1)),
     "collect: 1000000000000 trajectories of data.T=0.1 s at Δ = 0.01 s are 1.1e+13 samples, about 6.16e+05 GB"),
    ("Box str", lambda: Box(3, "a", "b"), "data.sampler.low='a': give a finite number or a list"),
    ("Box empty", lambda: Box(3, [], []), "data.sampler.low=[]: give a finite number"),
    ("Box 2-D", lambda: Box(3, [[-1, -1]], [[1, 1]]), "data.sampler.low=[[-1, -1]]: give a finite number"),
    ("Box bool", lambda: Box(3, True, 2), "data.sampler.low=True"),
    ("Box lengths", lambda: Box(3, [-1, -1], [1, 1, 1]), "must have the same length"),
    ("Box low >= high", lambda: Box(3, [-1, 1], [1, 1]), "need finite low < high"),
    ("Box n on collect", lambda: collect(VDP, Box(3, [-1] * 3, [1] * 3), DataConfig(T=0.1)),
     "have 3 entries, but the system has n=2: give one number or 2"),
    ("Points [[]]", lambda: Points([[]]), "non-empty list of states, got shape (1, 0)"),
    ("Points ragged", lambda: Points([[1, 2], [3]]), "data.sampler.points=[[1, 2], [3]]: give a list of states"),
    ("Points str", lambda: Points("ab"), "data.sampler.points='ab': give a list of states"),
    ("Points str numbers", lambda: Points([["1", "2"]]), "give a list of states"),
    ("Points flat", lambda: Points([1, 2]), "data.sampler.points=[1, 2]: give a list of states"),
    ("DataConfig filter None", lambda: DataConfig(filter=None), "data.filter=None: expected a RegionFilter"),
    ("DataConfig integrator None", lambda: DataConfig(integrator=None),
     "data.integrator=None: expected an IntegratorOptions"),
    ("DataConfig excitation str", lambda: DataConfig(excitation="uniform"),
     "data.excitation='uniform': expected an Excitation"),
    ("DataConfig source None", lambda: DataConfig(source=None), "data.source=None: expected a DataSource"),
    ("DataConfig pairs list", lambda: DataConfig(pairs=["next"]), "data.pairs=['next']; valid:"),
    ("DataConfig T=0.015", lambda: DataConfig(T=0.015, dt=0.01),
     "data.T=0.015: not a whole number of data.dt=0.01 steps (T/dt = 1.5); use data.T=0.02 (2 steps)"),
    ("DataConfig T=1 dt=0.3", lambda: DataConfig(T=1, dt=0.3), "use data.T=0.9 (3 steps)"),
    ("DataConfig T/dt inf", lambda: DataConfig(T=1e300, dt=1e-300), "T/dt is not a finite number of steps"),
    ("collect files", lambda: collect(VDP, Circle(3, 1.0), DataConfig(
        T=0.1, source=DataSource(kind="files", path="/nowhere"))), "read recorded runs with kexp.data.read_runs"),
    ("collect system None", lambda: collect(None, Circle(3, 1.0), DataConfig(T=0.1)),
     "collect: system=None: expected a ControlAffineSystem"),
    ("collect sampler dict", lambda: collect(VDP, {"kind": "circle"}, DataConfig(T=0.1)),
     "collect: sampler={'kind': 'circle'}: expected an initial-condition sampler"),
    ("collect config dict", lambda: collect(VDP, Circle(3, 1.0), {"T": 1.0}),
     "collect: config={'T': 1.0}: expected a DataConfig"),
    ("collect config None", lambda: collect(VDP, Circle(3, 1.0), None), "collect: config=None"),
    ("RegionFilter low > high", lambda: RegionFilter(low=(1,), high=(-1,)), "data.filter: need low < high"),
    ("RegionFilter str", lambda: RegionFilter(low="a"), "data.filter.low='a': give a number, or one per state"),
    ("RegionFilter NaN", lambda: RegionFilter(low=(nan, nan)), "data.filter.low=(nan, nan): a bound is NaN"),
    ("RegionFilter lengths", lambda: RegionFilter(low=(0, 0), high=(1, 1, 1)), "give the same number of bounds"),
    ("RegionFilter empty", lambda: RegionFilter(high=()), "data.filter.high=(): give a number"),
    ("RegionFilter NaN collect", lambda: short(filter=RegionFilter(low=(nan, nan))), "a bound is NaN"),
    ("Integrator batch 2.5", lambda: IntegratorOptions(batch=2.5), "data.integrator.batch=2.5: expected an integer"),
    ("Integrator batch True", lambda: IntegratorOptions(batch=True), "data.integrator.batch=True"),
    ("Integrator batch None", lambda: IntegratorOptions(batch=None), "data.integrator.batch=None"),
    ("Integrator rtol str", lambda: IntegratorOptions(rtol="a"), "data.integrator.rtol='a': expected a number"),
    ("Integrator method None", lambda: IntegratorOptions(method=None), "data.integrator.method=None; valid:"),
    ("Excitation frequencies str", lambda: Excitation(frequencies="1.0"),
     "data.excitation.frequencies='1.0': give a list of frequencies in Hz"),
    ("Excitation frequencies str items", lambda: Excitation(frequencies=["1.0"]), "give a list of frequencies"),
    ("Excitation kind list", lambda: Excitation(kind=["uniform"]), "data.excitation.kind=['uniform']; valid:"),
    ("DataSource path int", lambda: DataSource(kind="files", path=123), "data.source.path=123: give a path"),
]

FIXTURE = [
    ("read_runs dt nan", lambda d, r: read_runs(r, n=2, m=1, dt=nan), "read_runs: dt=nan: use the runs' sampling"),
    ("read_runs dt str", lambda d, r: read_runs(r, n=2, m=1, dt="a"), "read_runs: dt='a': expected a number"),
    ("read_runs m=0", lambda d, r: read_runs(r, n=2, m=0, dt=0.01), "read_runs: m=0: use an int >= 1"),
    ("read_runs m=-1", lambda d, r: read_runs(r, n=2, m=-1, dt=0.01), "read_runs: m=-1: use an int >= 1"),
    ("read_runs n str", lambda d, r: read_runs(r, n="2", m=1, dt=0.01), "read_runs: n='2': expected an integer"),
    ("read_runs n float", lambda d, r: read_runs(r, n=2.0, m=1, dt=0.01), "read_runs: n=2.0: expected an integer"),
    ("read_runs n bool", lambda d, r: read_runs(r, n=True, m=1, dt=0.01), "read_runs: n=True"),
    ("read_runs m bool", lambda d, r: read_runs(r, n=2, m=True, dt=0.01), "read_runs: m=True"),
    ("read_runs x_eq length", lambda d, r: read_runs(r, n=2, m=1, dt=0.01, x_eq=[1, 2, 3]),
     "read_runs: x_eq=[1, 2, 3]: give 2 finite number(s)"),
    ("read_runs x_eq nan", lambda d, r: read_runs(r, n=2, m=1, dt=0.01, x_eq=[nan, 0]), "x_eq=[nan, 0]"),
    ("read_runs filter str", lambda d, r: read_runs(r, n=2, m=1, dt=0.01, region_filter="a"),
     "read_runs: region_filter='a': expected a RegionFilter or None"),
    ("read_runs drift int", lambda d, r: read_runs(r, n=2, m=1, dt=0.01, pair_rule="euler", drift=5),
     "read_runs: drift=5: give the system's drift F"),
    ("read_runs pairs", lambda d, r: read_runs(r, n=2, m=1, dt=0.01, pair_rule="x"), "data.pairs='x'; valid:"),
    ("read_runs path None", lambda d, r: read_runs(None, n=2, m=1, dt=0.01), "read_runs: path=None: give a path"),
    ("open_runs dt nan", lambda d, r: open_runs(r, n=2, m=1, dt=nan), "open_runs: dt=nan"),
    ("open_runs n=0", lambda d, r: open_runs(r, n=0, m=1, dt=0.01), "open_runs: n=0: use an int >= 1"),
    ("open_runs x_eq", lambda d, r: open_runs(r, n=2, m=1, dt=0.01, x_eq=[0, 0, 0]), "open_runs: x_eq=[0, 0, 0]"),
    ("noise x_eq nan", lambda d, r: add_measurement_noise(d, 0.01, x_eq=[nan, 0]),
     "add_measurement_noise: x_eq=[nan, 0]: give 2 finite number(s)"),
    ("noise x_eq length", lambda d, r: add_measurement_noise(d, 0.01, x_eq=[0, 0, 0]), "x_eq=[0, 0, 0]"),
    ("noise dataset None", lambda d, r: add_measurement_noise(None, 0.01), "expected a Dataset or RecordedRuns"),
    ("data_rms x_eq length", lambda d, r: data_rms(d, [0, 0, 0]), "data_rms: x_eq=[0, 0, 0]"),
    ("data_rms x_eq str", lambda d, r: data_rms(d, "ab"), "data_rms: x_eq='ab'"),
    ("write_runs None", lambda d, r: write_runs(None, r), "write_runs: dataset=None: expected a Dataset"),
    ("write_runs dict", lambda d, r: write_runs({"x": 1}, r), "write_runs: dataset={'x': 1}: expected a Dataset"),
    ("write_runs folder None", lambda d, r: write_runs(d, None), "write_runs: folder=None: give a path"),
    ("Dataset dt nan", lambda d, r: _dataset(d, dt=nan), "Dataset.dt=nan: use the sampling time"),
    ("Dataset dt str", lambda d, r: _dataset(d, dt="0.01"), "Dataset.dt='0.01'"),
]

DATA = [
    ("Dataset t length", lambda d: _dataset(d, t=d.t[:-1]), "Dataset.t shape (20,) must be (T+1,) = (21,)"),
    ("Dataset t spacing", lambda d: _dataset(d, dt=0.05), "Dataset.t[1] - t[0] = 0.01, but dt=0.05"),
    ("Dataset t irregular", lambda d: _dataset(d, t=np.r_[d.t[:-1], 1.0]), "Dataset.t[20] - t[19]"),
    ("Dataset valid ints", lambda d: _dataset(d, valid=d.valid.astype(int)), "Dataset.valid has dtype int64"),
]


def _dataset(d, **kw):
    args = dict(t=d.t, x=d.x, valid=d.valid, dt=d.dt, pair_rule=d.pair_rule, system_name=d.system_name)
    return Dataset(**{**args, **kw})


def _one_line(exc, fragment):
    msg = str(exc.value)
    assert "\n" not in msg and fragment in msg, msg


@pytest.mark.parametrize("call,fragment", [c[1:] for c in CONFIG], ids=[c[0] for c in CONFIG])
def test_bad_arguments_are_refused_in_one_line(call, fragment):
    with pytest.raises(ConfigError) as exc:
        call()
    _one_line(exc, fragment)


@pytest.mark.parametrize("call,fragment", [c[1:] for c in FIXTURE], ids=[c[0] for c in FIXTURE])
def test_bad_reader_and_noise_arguments_are_refused_in_one_line(call, fragment, ds, runs):
    with pytest.raises(ConfigError) as exc:
        call(ds, runs)
    _one_line(exc, fragment)


@pytest.mark.parametrize("call,fragment", [c[1:] for c in DATA], ids=[c[0] for c in DATA])
def test_inconsistent_datasets_are_refused_in_one_line(call, fragment, ds):
    with pytest.raises(DataError) as exc:
        call(ds)
    _one_line(exc, fragment)


def test_valid_collection_gives_the_same_bits_as_the_old_recipe():
    """collect = sampler draws from default_rng(seed), then integrate over arange(n_steps + 1)·dt."""
    for sampler in (Circle(5, 1.5), Box(4, (-1.0, -2.0), 1.0), Points([[0.5, -0.25], [1, 2]])):
        ds = collect(VDP, sampler, DataConfig(T=0.5, seed=7))
        if isinstance(sampler, Circle):
            a = np.random.default_rng(7).uniform(0, 2 * np.pi, 5)
            x0 = 1.5 * np.stack([np.cos(a), np.sin(a)], axis=1)
        elif isinstance(sampler, Box):
            x0 = np.random.default_rng(7).uniform(np.array([-1.0, -2.0]), np.array([1.0, 1.0]), (4, 2))
        else:
            x0 = np.array([[0.5, -0.25], [1.0, 2.0]])
        t = np.arange(51) * 0.01
        assert np.array_equal(ds.t, t) and np.array_equal(ds.x, integrate(VDP, x0, t, None, IntegratorOptions()))
    even = Circle(4, 1.0, even=True).sample(np.zeros(2), 0)
    assert np.array_equal(even, np.stack([np.cos(np.arange(4) / 4 * 2 * np.pi),
                                          np.sin(np.arange(4) / 4 * 2 * np.pi)], axis=1))


def test_valid_edge_values_are_still_accepted(ds, runs):
    assert DataConfig(T=3.3, dt=0.01).n_steps == 330 and DataConfig(T=1e7).n_steps == 10 ** 9
    # T/dt just below a whole number in floating point (0.57/0.01 = 56.99999999999999) rounds, not truncates
    assert DataConfig(T=0.57).n_steps == 57 and DataConfig(T=2.01).n_steps == 201
    from kexp.simulate import SimConfig
    assert SimConfig(T=0.57).n_steps == 57 and SimConfig(T=1.13, dt=0.01).n_steps == 113
    assert DataConfig(T=10.0, dt=0.03, source=DataSource(kind="files", path="runs")).dt == 0.03  # T does not apply
    assert Box(2, [-1], [1, 1]).sample(np.zeros(2), 0).shape == (2, 2)     # one bound broadcasts, as before
    assert Points(np.array([[1, 2]])).n_traj == 1 and Circle(np.int64(3), np.float64(1.0)).n_traj == 3
    flt = RegionFilter(low=[-np.pi, None], high=(np.pi, None))
    assert flt.describe(2) == "[-3.14159, 3.14159] × [-inf, inf]"
    assert Excitation(frequencies=0.5).frequencies == (0.5,)
    back = read_runs(runs, n=2, m=1, dt=0.01, x_eq=np.zeros(2), region_filter=RegionFilter(),
                     drift=VDP.drift, system_name="vanderpol")
    assert np.array_equal(back.x, ds.x) and np.array_equal(back.t, ds.t)
    assert np.array_equal(data_rms(ds, (0, 0)), data_rms(ds))
    noisy = add_measurement_noise(ds, 0.01, x_eq=VDP.equilibrium, seed=3)
    assert np.array_equal(noisy.x, ds.with_noise(0.01 * data_rms(ds), 3).x)
    assert collect(VDP, SimpleNamespace(n_traj=2, sample=lambda c, s: np.ones((2, 2))), DataConfig(T=0.1)).n_traj == 2
