"""The fold guards' distinct-index sets: ``np.unique``'s results, without its sort."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from warpface.expression import fold_guard


@given(
    size=st.integers(1, 200),
    data=st.data(),
)
def test_distinct_sets_are_numpy_s_unique_and_leave_the_scratch_clean(size, data):
    ids = data.draw(
        arrays(np.int64, st.tuples(st.integers(0, 60), st.sampled_from([1, 3])), elements=st.integers(0, size - 1))
    )
    marks, slots = np.zeros(size, dtype=bool), np.full(size, -7, dtype=np.intp)
    distinct, inverse = fold_guard._distinct_with_inverse(ids, marks, slots)
    expected, expected_inverse = np.unique(ids, return_inverse=True)
    np.testing.assert_array_equal(distinct, expected)
    np.testing.assert_array_equal(inverse, expected_inverse.reshape(ids.shape))
    assert inverse.shape == ids.shape
    assert not marks.any()
    np.testing.assert_array_equal(fold_guard._distinct(ids.ravel(), marks), expected)
    assert not marks.any()
