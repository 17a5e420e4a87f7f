"""The tracker's assignment solver against scipy's (the reference) on random matrices."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.optimize import linear_sum_assignment

from stereod.tracking.assignment import min_cost_assignment

costs = st.tuples(st.integers(1, 7), st.integers(1, 7)).flatmap(
    lambda shape: arrays(
        np.float64, shape, elements=st.floats(-1e3, 1e3, allow_nan=False, width=32)
    )
)


@settings(max_examples=300, deadline=None)
@given(costs)
def test_total_cost_equals_scipy(cost: np.ndarray) -> None:
    rows, cols = min_cost_assignment(cost)
    ref_rows, ref_cols = linear_sum_assignment(cost)
    assert len(rows) == min(cost.shape)
    assert len(set(rows.tolist())) == len(rows) and len(set(cols.tolist())) == len(cols)
    assert np.all(np.diff(rows) > 0)
    assert cost[rows, cols].sum() == pytest.approx(cost[ref_rows, ref_cols].sum(), abs=1e-6)


def test_forbidden_pairs_by_large_cost() -> None:
    big = 1e9
    cost = np.array([[1.0, big], [big, 2.0], [0.5, big]])
    rows, cols = min_cost_assignment(cost)
    assert dict(zip(rows.tolist(), cols.tolist())) == {1: 1, 2: 0}


def test_empty_and_invalid() -> None:
    rows, cols = min_cost_assignment(np.zeros((0, 3)))
    assert rows.size == cols.size == 0
    with pytest.raises(ValueError, match="finite"):
        min_cost_assignment(np.array([[np.inf]]))
