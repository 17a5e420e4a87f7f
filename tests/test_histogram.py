"""Latencies counted in fixed bins: the percentiles read back from two readings' difference
agree with numpy's of the same values within a bin's width."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stereod.fusion.histogram import (
    EDGES_MS,
    LatencyHistogram,
    difference,
    quantile_ms,
    share_within,
)


def test_a_value_on_an_edge_is_counted_in_the_bin_it_ends() -> None:
    h = LatencyHistogram()
    h.add([0.0, 0.5, 0.50001, 10.0, 5000.0, 5000.1])
    assert h.counts[0] == 2  # 0 and 0.5: (0, 0.5]
    assert h.counts[1] == 1
    assert h.counts[EDGES_MS.index(10.0)] == 1
    assert h.counts[len(EDGES_MS) - 1] == 1 and h.counts[-1] == 1  # 5000, and beyond it
    assert sum(h.counts) == 6


def test_quantiles_of_the_difference_match_numpy_within_a_bin() -> None:
    """Exponential latencies (mean 3 ms) after a first reading of slow ones: the difference
    holds only the second lot, whose p50, p99 and p99.9 lie within the width of their bin of
    numpy's, and whose share within 10 ms is exactly the count's."""
    rng = np.random.default_rng(0)
    h = LatencyHistogram()
    h.add([300.0] * 50)
    first = list(h.counts)
    values = rng.exponential(3.0, 20_000)
    h.add(values.tolist())
    between = difference(h.counts, first)
    assert sum(between) == len(values)
    for q in (0.5, 0.99, 0.999):
        truth = float(np.quantile(values, q))
        k = int(np.searchsorted(EDGES_MS, truth))
        width = EDGES_MS[k] - (EDGES_MS[k - 1] if k else 0.0)
        assert abs(quantile_ms(between, q) - truth) <= width
    assert share_within(between, 10.0) == pytest.approx(float(np.mean(values <= 10.0)), abs=1e-12)


def test_beyond_the_last_edge_is_infinite_and_nothing_is_nan() -> None:
    h = LatencyHistogram()
    assert math.isnan(quantile_ms(h.counts, 0.99))
    assert math.isnan(share_within(h.counts, 10.0))
    h.add([1.0] * 98 + [9000.0] * 2)
    assert quantile_ms(h.counts, 0.98) <= 1.0
    assert quantile_ms(h.counts, 0.99) == math.inf


def test_bad_arguments_are_refused() -> None:
    h = LatencyHistogram()
    with pytest.raises(ValueError, match="not in"):
        quantile_ms(h.counts, 0.0)
    with pytest.raises(ValueError, match="counts for"):
        quantile_ms(h.counts[:-1], 0.5)
    with pytest.raises(ValueError, match="bins"):
        difference(h.counts, h.counts[:-1])
    with pytest.raises(ValueError, match="not a bin edge"):
        share_within(h.counts, 9.9)
    with pytest.raises(ValueError, match="counts for"):
        share_within([], 10.0)


def test_within_a_bin_the_quantile_is_interpolated_from_its_lower_edge() -> None:
    """Four values in the first bin, (0, 0.5] ms: the median lies halfway into it, from 0;
    eight in (10, 10.5]: their 25th percentile a quarter of the way from 10 ms; q = 1 is the
    upper edge of the last bin holding any."""
    first = LatencyHistogram()
    first.add([0.1, 0.2, 0.3, 0.4])
    assert quantile_ms(first.counts, 0.5) == pytest.approx(0.25, rel=1e-6)
    h = LatencyHistogram()
    h.add([10.2] * 8)
    assert quantile_ms(h.counts, 0.25) == pytest.approx(10.125, rel=1e-6)
    assert quantile_ms(h.counts, 1.0) == pytest.approx(10.5, rel=1e-6)


def test_a_rank_on_a_whole_count_stays_in_its_bin() -> None:
    """7 of 100 in one bin and the rest beyond the last edge: the 7th percentile is that bin's
    (0.07 x 100 is 7.000000000000001 in floating point)."""
    h = LatencyHistogram()
    h.add([1.0] * 7 + [9000.0] * 93)
    assert quantile_ms(h.counts, 0.07) == pytest.approx(1.0, rel=1e-6)


def test_readings_of_another_node_or_none_are_refused() -> None:
    """A node started again between two readings (a count went down), and a node older than
    the histogram (no bins), are said so rather than read as latencies."""
    h = LatencyHistogram()
    h.add([1.0, 2.0])
    later = LatencyHistogram()
    later.add([1.0])
    with pytest.raises(ValueError, match="started again"):
        difference(later.counts, h.counts)
    with pytest.raises(ValueError, match="older than"):
        difference([], [])
