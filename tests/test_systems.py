import sys
import textwrap

import numpy as np
import pytest

from kexp.errors import SystemDefinitionError
from kexp.systems import SYSTEMS, Pendulum, SlowManifold, VanDerPol, make_system


# each shipped system's equations at its default parameters, written out here: (x1, x2, u) -> (ẋ1, ẋ2)
EQUATIONS = {
    "cart_pendulum": lambda x1, x2, u: (x2, np.sin(x1) - 0.1 * x2 - np.cos(x1) * u),
    "duffing": lambda x1, x2, u: (x2, -0.5 * x2 + x1 - x1 ** 3 + u),
    "linear": lambda x1, x2, u: (x2, -2.0 * x1 - 0.3 * x2 + u),
    "pendulum": lambda x1, x2, u: (x2, 0.01 * x2 - np.sin(x1) + u),
    "slow_manifold": lambda x1, x2, u: (-0.3 * x1, -(x2 - x1 ** 2) + u),
    "vanderpol": lambda x1, x2, u: (x2, (1 - x1 ** 2) * x2 - x1 + u),
}


@pytest.mark.parametrize("name", sorted(SYSTEMS))
def test_shipped_systems_pass_checks_and_vanish_at_equilibrium(name):
    """Each shipped system's F and G give its equations (written out in EQUATIONS) at random states and inputs, with
    and without the input, over a batch and a single state."""
    assert sorted(EQUATIONS) == sorted(SYSTEMS)
    s = make_system(name)
    rng = np.random.default_rng(0)
    x = s.equilibrium + rng.normal(size=(7, s.n))
    u = rng.normal(size=(7, s.m))
    want = np.stack(EQUATIONS[name](x[:, 0], x[:, 1], u[:, 0]), axis=-1)
    free = np.stack(EQUATIONS[name](x[:, 0], x[:, 1], 0.0 * u[:, 0]), axis=-1)
    assert s.rhs(x, u).shape == (7, s.n) and np.allclose(s.rhs(x, u), want, rtol=1e-14, atol=1e-14)
    assert s.rhs(x).shape == (7, s.n) and np.allclose(s.rhs(x), free, rtol=1e-14, atol=1e-14)
    assert np.allclose(s.rhs(x[3], u[3]), want[3], rtol=1e-14, atol=1e-14)
    assert np.max(np.abs(want - free)) > 0.1                      # the input acts
    assert np.allclose(s.drift(s.equilibrium[None]), 0.0)
    assert len(s.state_names) == s.n


def test_paper_equations():
    x = np.array([[0.7, -1.3]])
    assert np.allclose(VanDerPol().rhs(x, np.array([[2.0]])), [[-1.3, (1 - 0.49) * -1.3 - 0.7 + 2.0]])
    assert np.allclose(Pendulum().rhs(x, np.array([[2.0]])), [[-1.3, 0.01 * -1.3 - np.sin(0.7) + 2.0]])


def test_pendulum_wraps_angle_only():
    p = Pendulum()
    w = p.wrap(np.array([[np.pi + 0.5, 9.0], [-np.pi - 0.5, -9.0]]))
    assert np.allclose(w, [[-np.pi + 0.5, 9.0], [np.pi - 0.5, -9.0]])


def test_multi_input_system():
    s = make_system("slow_manifold", {"inputs": "both"})
    assert s.m == 2
    x = np.array([[0.5, 0.2]])
    assert np.allclose(s.rhs(x, np.array([[1.0, -2.0]])), s.drift(x) + [[1.0, -2.0]])


def test_user_system_from_module_path(tmp_path, monkeypatch):
    (tmp_path / "my_systems.py").write_text(textwrap.dedent("""
        from dataclasses import dataclass
        from typing import ClassVar
        import numpy as np
        from kexp.systems import ControlAffineSystem

        @dataclass(frozen=True)
        class Cubic(ControlAffineSystem):
            a: float = 1.0
            name: ClassVar[str] = "cubic"
            n: ClassVar[int] = 1
            m: ClassVar[int] = 1
            def drift(self, x):
                return self.a * np.asarray(x) ** 3
            def input_matrix(self, x):
                return np.ones(np.shape(x) + (1,))

        @dataclass(frozen=True)
        class BadShape(Cubic):
            def drift(self, x):
                return np.zeros(3)

        @dataclass(frozen=True)
        class NaNs(Cubic):
            def input_matrix(self, x):
                return np.full(np.shape(x) + (1,), np.nan)
        """))
    monkeypatch.syspath_prepend(str(tmp_path))
    s = make_system("my_systems:Cubic", {"a": 2.0})
    assert s.a == 2.0 and s.n == 1
    with pytest.raises(SystemDefinitionError, match=r"drift\(x\) returned shape \(3,\)"):
        make_system("my_systems:BadShape")
    with pytest.raises(SystemDefinitionError, match="NaN"):
        make_system("my_systems:NaNs")
    with pytest.raises(SystemDefinitionError, match="bad parameters"):
        make_system("my_systems:Cubic", {"b": 1})
    sys.modules.pop("my_systems", None)


def test_unknown_system_names_valid_ones():
    with pytest.raises(SystemDefinitionError, match="vanderpol"):
        make_system("vanderpool")


def test_slow_manifold_eigenpairs_are_exact():
    s = SlowManifold(mu=-0.4, lam=-1.5)
    x = np.random.default_rng(1).normal(size=(5, 2))
    basis = np.stack([np.ones(5), x[:, 0], x[:, 1], x[:, 0] ** 2], axis=1)
    jac = np.stack([np.zeros((5, 2)), np.tile([1, 0], (5, 1)), np.tile([0, 1], (5, 1)),
                    np.stack([2 * x[:, 0], np.zeros(5)], 1)], axis=1)
    for lam, w in s.eigenpairs().items():
        lie = np.einsum("kNn,kn->kN", jac, s.drift(x)) @ np.asarray(w, float)
        assert np.allclose(lie, lam * basis @ np.asarray(w, float), atol=1e-12)
