import tracemalloc

import numpy as np
import pytest

from kexp.dictionary import Monomials
from kexp.errors import DataError
from kexp.identify.edmd import fit_least_squares

D = Monomials(2, 5)


def pairs(n_pairs, chunk, seed=0):
    rng = np.random.default_rng(seed)
    a = np.array([[0.995, 0.05], [-0.05, 0.99]])
    done = 0
    while done < n_pairs:
        rows = min(chunk, n_pairs - done)
        x = rng.uniform(-1, 1, (rows, 2))
        y = x @ a.T + 0.01 * x ** 3
        yield x, y
        done += rows


@pytest.mark.parametrize("method", ["qr", "gram"])
def test_same_k_for_any_chunk_size(method):
    ref = fit_least_squares(pairs(30000, 30000), D.lift, method=method).K
    for chunk in (1, 37, 1000, 7777):
        if chunk == 1:  # chunk size one row is legal, just slow: use a short stream
            continue
        # the same data arrives in different chunk sizes when regenerated row-wise: build it explicitly
        x, y = next(pairs(30000, 30000))
        stream = ((x[i:i + chunk], y[i:i + chunk]) for i in range(0, 30000, chunk))
        k = fit_least_squares(stream, D.lift, method=method).K
        assert np.max(np.abs(k - ref)) < (1e-11 if method == "qr" else 1e-8)
    x, y = next(pairs(300, 300))
    one = fit_least_squares(((x[i:i + 1], y[i:i + 1]) for i in range(300)), D.lift, method=method).K
    ref_small = fit_least_squares([(x, y)], D.lift, method=method).K
    assert np.max(np.abs(one - ref_small)) < 1e-8


def test_qr_matches_dense_least_squares():
    x, y = next(pairs(20000, 20000))
    k_ref = np.linalg.lstsq(D.lift(x), D.lift(y), rcond=None)[0].T
    fit = fit_least_squares([(x, y)], D.lift)
    assert np.max(np.abs(fit.K - k_ref)) < 1e-11
    assert fit.rank == 21
    assert abs(fit.cond - np.linalg.cond(D.lift(x))) < 1e-8 * fit.cond


def _peak(n_pairs):
    tracemalloc.start()
    fit_least_squares(pairs(n_pairs, 5000), D.lift, method="qr")
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak


def test_memory_independent_of_sample_count():
    small, large = _peak(20000), _peak(200000)
    # chunks of 5000 rows × (21 + 21) columns × 8 bytes ≈ 1.7 MB each; ten times the data, same peak
    assert large < 1.2 * small, (small, large)
    # a few chunk-sized buffers, far below the lifted data matrices (200000 × 42 × 8 B = 67 MB)
    assert large < 0.25 * 200000 * 42 * 8


def test_too_few_pairs_is_a_clear_error():
    with pytest.raises(DataError, match="at least 21"):
        fit_least_squares(pairs(10, 10), D.lift)
    with pytest.raises(DataError, match="NaN"):
        fit_least_squares([(np.full((30, 2), np.nan), np.zeros((30, 2)))], D.lift)
