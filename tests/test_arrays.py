"""The sort-based set operations give NumPy's results (values, order, counts, shapes)."""
import numpy as np
import pytest

from photorecon.arrays import isin, unique_rows, unique_sorted


@pytest.mark.parametrize("dtype", [np.int32, np.int64])
def test_unique_sorted_and_rows_match_numpy(dtype):
    rng = np.random.default_rng(3)
    a = rng.integers(-500, 500, (4000, 3)).astype(dtype)
    a = np.concatenate([a, a[:700]])  # repeated rows and values
    u = unique_sorted(a)
    assert u.dtype == a.dtype and np.array_equal(u, np.unique(a))
    u, c = unique_sorted(a, return_counts=True)
    ref_u, ref_c = np.unique(a, return_counts=True)
    assert np.array_equal(u, ref_u) and np.array_equal(c, ref_c) and c.max() > 1
    r = unique_rows(a)
    assert r.dtype == a.dtype and np.array_equal(r, np.unique(a, axis=0)) and len(r) < len(a)
    r, c = unique_rows(a, return_counts=True)
    ref_r, ref_c = np.unique(a, axis=0, return_counts=True)
    assert np.array_equal(r, ref_r) and np.array_equal(c, ref_c) and c.max() == 2
    far = a.copy()
    far[0, 0] = 1 << 22  # beyond the 21-bit keys: NumPy's own path, the same answer
    assert np.array_equal(unique_rows(far), np.unique(far, axis=0))
    assert len(unique_sorted(a[:0])) == 0 and unique_rows(a[:0]).shape == (0, 3)


def test_isin_matches_numpy():
    rng = np.random.default_rng(4)
    a = rng.integers(0, 10**12, (300, 3))
    b = np.concatenate([a[::7].ravel(), rng.integers(0, 10**12, 50)])
    got = isin(a, b)
    assert got.shape == a.shape and np.array_equal(got, np.isin(a, b)) and 0 < got.sum() < got.size
    assert not isin(a, np.zeros(0, np.int64)).any()
