import numpy as np
import pytest

from kexp.dictionary import Monomials
from kexp.errors import ConfigError


@pytest.mark.parametrize("n,degree,const,size", [(2, 5, True, 21), (2, 5, False, 20), (4, 5, True, 126),
                                                  (3, 2, True, 10), (1, 4, True, 5)])
def test_sizes(n, degree, const, size):
    assert Monomials(n, degree, include_constant=const).size == size


def test_order_is_graded_lexicographic():
    assert Monomials(2, 2).names() == ["1", "x1", "x2", "x1^2", "x1*x2", "x2^2"]
    assert Monomials(2, 2, weights=(1, 2)).names() == ["1", "x1", "x2", "x1^2"]


@pytest.mark.parametrize("n,degree,scale", [(2, 5, None), (3, 4, (2.0, 0.5, 1.5)), (4, 3, None)])
def test_lift_and_analytic_jacobian(n, degree, scale):
    d = Monomials(n, degree, scale=scale)
    x = np.random.default_rng(0).normal(size=(6, n))
    s = np.ones(n) if scale is None else np.asarray(scale)
    phi = d.lift(x)
    expected = np.prod((x / s)[:, None, :] ** d.exponents[None], axis=-1)
    assert np.allclose(phi, expected, rtol=1e-13)
    eps = 1e-6
    num = np.stack([(d.lift(x + eps * np.eye(n)[i]) - d.lift(x - eps * np.eye(n)[i])) / (2 * eps)
                    for i in range(n)], axis=-1)
    assert np.max(np.abs(d.jacobian(x) - num)) < 1e-6 * max(1.0, np.max(np.abs(num)))
    v = np.random.default_rng(1).normal(size=(6, n))
    assert np.allclose(d.lie(x, v), np.einsum("kNn,kn->kN", d.jacobian(x), v))


def test_validation_messages():
    with pytest.raises(ConfigError, match="degree"):
        Monomials(2, 0)
    with pytest.raises(ConfigError, match="lower the degree"):
        Monomials(10, 12)
    with pytest.raises(ConfigError, match="scale"):
        Monomials(2, 3, scale=(1.0, -1.0))


def test_spec_round_trip():
    d = Monomials(3, 4, include_constant=False, weights=(1, 2, 1), scale=(1.0, 2.0, 3.0))
    d2 = Monomials.from_spec(d.spec())
    assert d2 == d and np.array_equal(d2.exponents, d.exponents)


@pytest.mark.parametrize("d", [Monomials(2, 5), Monomials(3, 4, scale=(2.0, 0.5, 3.0)),
                               Monomials(2, 6, weights=(1, 2)), Monomials(2, 5, include_constant=False)],
                         ids=["2x5", "3x4_scaled", "weighted", "no_constant"])
def test_lifting_one_state_is_bit_identical_to_the_batch(d):
    """The closed loop lifts one state per step through a path on Python floats: the same multiplications in the
    same order as the batched lift, so the same bits (also for 0, NaN and huge states)."""
    rng = np.random.default_rng(0)
    X = rng.uniform(-3, 3, (300, d.n))
    X[0], X[1], X[2] = 0.0, np.nan, 1e200
    with np.errstate(all="ignore"):
        batch = d.lift(X)
        one = np.vstack([d.lift(x) for x in X])
    assert np.array_equal(batch, one, equal_nan=True)
