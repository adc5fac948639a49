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
    for v in (rng.uniform(-50, 2100, 500), np.round(rng.uniform(0, 10, 300)), np.array([1.0, 1.0, 1.0]), np.array([4.2])):
        kv = KVector(v)
        order, s, k, a1, b1 = kvector_build(v)
        assert np.array_equal(order, kv.order) and np.array_equal(s, kv.sorted_values) and np.array_equal(k, kv.k)
        assert (a1, b1) == (kv.a1, kv.b1)
