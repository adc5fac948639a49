"""k-vector range search: paper 000's Table A1 and exact agreement with a brute-force search."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from startracker.kvector import KVector


def test_paper000_table_a1():
    xs = [506.4, 23.2, 105.8, 1023.2, 243.1, 132.7]
    kv = KVector(xs)
    assert kv.k.tolist() == [0, 3, 4, 5, 5, 6]
    assert kv.a1 == 240.0 and abs(kv.b1 - (-316.8)) < 1e-12
    assert (kv.order + 1).tolist() == [2, 3, 6, 5, 1, 4]  # R_x, 1-based as in the paper
    ia, ib = kv.line_indices(246.7 - 5, 246.7 + 5)
    assert (int(ia), int(ib)) == (2, 3)
    ys = [45.6, 347.9, 78.5, 732.6, 381.5, 176.3]
    ky = KVector(ys)
    assert ky.k.tolist() == [0, 2, 3, 5, 5, 6]
    assert [int(v) for v in ky.line_indices(378.5 - 5, 378.5 + 5)] == [3, 4]


@settings(max_examples=300, deadline=None)
@given(
    st.lists(st.floats(-1e3, 1e3, allow_nan=False), min_size=1, max_size=60),
    st.lists(st.tuples(st.floats(-1.2e3, 1.2e3), st.floats(0, 300)), min_size=1, max_size=20),
)
def test_equals_brute_force_range_search(values, queries):
    values = np.array(values)
    kv = KVector(values)
    lo = np.array([q[0] for q in queries])
    hi = lo + np.array([q[1] for q in queries])
    qi, ei = kv.query_many(lo, hi)
    got = sorted(zip(qi.tolist(), ei.tolist()))
    brute = sorted((q, e) for q in range(len(lo)) for e in range(len(values)) if lo[q] <= values[e] <= hi[q])
    assert got == brute


def test_duplicates_and_constant_values():
    kv = KVector([3.0, 3.0, 3.0])
    assert sorted(kv.query(3.0, 3.0).tolist()) == [0, 1, 2]
    assert kv.query(3.1, 4.0).size == 0


def test_compiled_kvector_equals_the_checked_kvector():
    from startracker.kernels.kvector import kvector_build

    rng = np.random.default_rng(5)
    cases = [rng.uniform(-50, 2100, 500), np.round(rng.uniform(0, 10, 300)), np.array([1.0, 1.0, 1.0]), np.array([4.2])]
    cases += [v for v in _sort_cases() if v.size] + [np.concatenate([rng.uniform(0, 1, 50), [1e6, -1e6]])]
    for v in cases:
        kv = KVector(v)
        order, s, k, a1, b1 = kvector_build(v)
        assert np.array_equal(order, kv.order) and np.array_equal(s, kv.sorted_values) and np.array_equal(k, kv.k)
        assert (a1, b1) == (kv.a1, kv.b1)


def _sort_cases():
    """Arrays with distinct values, many ties, a bin crowded past the bucket sort's insertion limit, a subnormal
    range (the bucket sort's fallback) and the short lengths of the insertion paths."""
    rng = np.random.default_rng(11)
    cases = [np.empty(0), np.array([2.5]), np.array([3.0, -1.0]), rng.normal(size=16), rng.normal(size=17)]
    cases += [rng.normal(size=1000), rng.integers(0, 4, 700).astype(float)]
    cases.append(np.concatenate([rng.normal(size=200), np.full(100, 0.25) + rng.normal(size=100) * 1e-12]))
    cases.append(1e-310 + rng.integers(0, 3, 300) * 5e-324)
    return cases


def test_compiled_stable_argsort_is_numpys_stable_permutation():
    from startracker.kernels.kvector import stable_argsort

    for v in _sort_cases():
        assert np.array_equal(stable_argsort(v), np.argsort(v, kind="stable"))


def test_compiled_median_and_search_equal_numpy():
    from startracker.kernels.kvector import median_value, search_sorted

    for v in _sort_cases():
        if v.size:  # bit for bit, the mean of the two middle values included
            assert np.float64(median_value(v)).tobytes() == np.median(v).tobytes()
        s = np.sort(v)
        for x in np.concatenate([s[:: max(1, s.size // 7)], [-np.inf, -3.0, 0.25, 3.0, np.inf]]):
            assert search_sorted(s, x, False) == np.searchsorted(s, x, side="left")
            assert search_sorted(s, x, True) == np.searchsorted(s, x, side="right")
    assert np.isnan(median_value(np.empty(0)))


def test_compiled_partition_selects_the_sorted_value_and_splits_around_it():
    from startracker.kernels.kvector import partition_values

    rng = np.random.default_rng(13)
    cases = [v for v in _sort_cases() if v.size]
    cases += [np.arange(100.0), np.arange(100.0)[::-1].copy(), np.tile([1.0, 0.0], 40), rng.normal(size=31)]
    for v in cases:
        v0 = v.copy()
        s = np.sort(v)
        ints = rng.integers(-40, 40, v.size)
        si = np.sort(ints)
        for k in sorted({0, v.size // 4, v.size // 2, v.size - 1, int(rng.integers(v.size))}):
            for a, ref in ((v, s), (ints, si)):
                p = partition_values(a, k)
                assert p.dtype == a.dtype and np.array_equal(np.sort(p), ref)  # a permutation of the values
                assert p[k] == ref[k]
                assert np.all(p[:k] <= p[k]) and np.all(p[k + 1:] >= p[k])
        assert np.array_equal(v, v0)  # the input is left alone
