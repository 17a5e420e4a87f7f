"""Latencies counted since start in fixed bins, so that a reader can take any two of the
fusion node's status replies and get the percentiles of exactly what happened between them
(the status's own p50 and p99 cover the last :data:`~stereod.fusion.status.WINDOW` rig
messages only: a second or two at 16 rigs, which a stall just before the reply dominates or
misses)."""

from __future__ import annotations

import bisect
import math
from collections.abc import Iterable, Sequence

EDGES_MS: tuple[float, ...] = (
    *(0.5 * k for k in range(1, 41)),
    25.0, 30.0, 40.0, 50.0, 60.0, 80.0, 100.0, 150.0, 200.0, 300.0, 500.0, 1000.0, 2000.0, 5000.0,
)  # fmt: skip
"""Upper edges of the bins (ms): half a millisecond wide up to 20 ms, where the fusion's
targets lie, coarser beyond. A last bin holds everything over the last edge."""


_RANK_SLACK = 1e-9
"""A quantile's rank is taken this much (relative) low: ``q * total`` in floating point can
land a hair above a whole count (0.07 x 100 is 7.000000000000001) and skip to the next bin."""


class LatencyHistogram:
    """Counts of latencies (ms) in the bins of :data:`EDGES_MS`: ``counts[k]`` of those in
    (``EDGES_MS[k - 1]``, ``EDGES_MS[k]``], the first from 0, the last beyond the last edge.
    Not locked: a caller shared between threads holds its own lock around :meth:`add` and
    copies :attr:`counts` under it."""

    def __init__(self) -> None:
        self.counts = [0] * (len(EDGES_MS) + 1)

    def add(self, values_ms: Iterable[float]) -> None:
        """Count each of ``values_ms`` (ms) in its bin."""
        for v in values_ms:
            self.counts[bisect.bisect_left(EDGES_MS, v)] += 1


def difference(later: Sequence[int], earlier: Sequence[int]) -> list[int]:
    """The counts added between two readings of one histogram (later minus earlier). Raises
    ValueError for readings that cannot be of one histogram in that order: no bins (a node
    older than the histogram), bins of another number, or a count that went down (the node
    started again between them)."""
    if not later or not earlier:
        raise ValueError("no latency histogram: the fusion node is older than added_ms_counts")
    if len(later) != len(earlier):
        raise ValueError(f"histograms of {len(later)} and {len(earlier)} bins")
    out = [a - b for a, b in zip(later, earlier, strict=True)]
    if min(out) < 0:
        raise ValueError("a count went down between the readings: the node started again")
    return out


def quantile_ms(counts: Sequence[int], q: float, edges: Sequence[float] = EDGES_MS) -> float:
    """The ``q``-quantile (0 < q <= 1) of the latencies behind ``counts`` (ms), taken linearly
    within its bin (so within a bin's width of the true one); ``inf`` when it lies beyond the
    last edge, ``nan`` with no count."""
    if not 0.0 < q <= 1.0:
        raise ValueError(f"quantile {q} is not in (0, 1]")
    if len(counts) != len(edges) + 1:
        raise ValueError(f"{len(counts)} counts for {len(edges)} edges (expected {len(edges) + 1})")
    total = sum(counts)
    if total == 0:
        return math.nan
    rank = q * total * (1.0 - _RANK_SLACK)
    below = 0
    for k, n in enumerate(counts):
        if n and below + n >= rank:
            if k == len(edges):
                return math.inf
            lo = edges[k - 1] if k else 0.0
            return lo + (edges[k] - lo) * (rank - below) / n
        below += n
    return math.inf  # (not reached: the counts sum to total)


def share_within(
    counts: Sequence[int], limit_ms: float, edges: Sequence[float] = EDGES_MS
) -> float:
    """The share of the latencies at most ``limit_ms``, which must be one of the ``edges``;
    ``nan`` with no count."""
    if len(counts) != len(edges) + 1:
        raise ValueError(f"{len(counts)} counts for {len(edges)} edges (expected {len(edges) + 1})")
    if limit_ms not in edges:
        raise ValueError(f"{limit_ms} ms is not a bin edge")
    total = sum(counts)
    if total == 0:
        return math.nan
    return sum(counts[: list(edges).index(limit_ms) + 1]) / total
