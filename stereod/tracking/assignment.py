"""Minimum-cost assignment (the Hungarian method) for the tracker's small cost matrices.

A scene has a handful of objects, so the matrices are tiny; this is the O(n^2 m) shortest
augmenting path form with row and column potentials (Kuhn-Munkres as Jonker and Volgenant
write it), vectorised over columns. It replaces ``scipy.optimize.linear_sum_assignment``,
whose import alone costs the daemon about 48 MB of resident memory; the tests check the two
agree on random matrices.
"""

from __future__ import annotations

import numpy as np


def min_cost_assignment(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of a minimum-total-cost matching of an (n, m) matrix of finite costs.

    Every row is matched when n <= m, every column when n > m, as
    ``scipy.optimize.linear_sum_assignment`` does; returns (k,) row and (k,) column indices,
    rows ascending, k = min(n, m).
    """
    c = np.asarray(cost, dtype=np.float64)
    if c.ndim != 2:
        raise ValueError(f"cost must be a 2-D matrix, got shape {c.shape}")
    if not np.all(np.isfinite(c)):
        raise ValueError("cost must be finite (use a large number for forbidden pairs)")
    n, m = c.shape
    if n == 0 or m == 0:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    if n == 1:  # one object or one track, the usual case: the cheapest partner
        return np.zeros(1, np.intp), np.array([int(np.argmin(c[0]))], np.intp)
    if m == 1:
        return np.array([int(np.argmin(c[:, 0]))], np.intp), np.zeros(1, np.intp)
    if n > m:
        cols, rows = min_cost_assignment(c.T)
        order = np.argsort(rows)
        return rows[order], cols[order]
    # 1-based arrays with a virtual column 0, as in the textbook form.
    u = np.zeros(n + 1)
    v = np.zeros(m + 1)
    match = np.zeros(m + 1, np.intp)  # match[j]: row matched to column j (0 = none)
    way = np.zeros(m + 1, np.intp)
    for i in range(1, n + 1):
        match[0] = i
        j0 = 0
        minv = np.full(m + 1, np.inf)
        used = np.zeros(m + 1, bool)
        while True:
            used[j0] = True
            i0 = match[j0]
            free = ~used[1:]
            reduced = c[i0 - 1] - u[i0] - v[1:]
            better = free & (reduced < minv[1:])
            minv[1:][better] = reduced[better]
            way[1:][better] = j0
            candidates = np.where(free, minv[1:], np.inf)
            j1 = int(np.argmin(candidates)) + 1
            delta = candidates[j1 - 1]
            u[match[used]] += delta
            v[used] -= delta
            minv[1:][free] -= delta
            j0 = j1
            if match[j0] == 0:
                break
        while j0:
            j1 = way[j0]
            match[j0] = match[j1]
            j0 = j1
    cols = np.flatnonzero(match[1:]).astype(np.intp)
    rows = match[1:][cols] - 1
    order = np.argsort(rows)
    return rows[order].astype(np.intp), cols[order]
