"""Every live rig track's room-frame state in one table, and the closed-form 3x3 algebra the
fusion runs on rows of it.

A rig's message writes its tracks' rows once, at arrival (moved into the room frame); a
fusion step then gathers only the rows it needs (the members of the room tracks that message
touches) with one index, predicts them to its instant and fuses them, each in a dozen numpy
calls on (n, 9) columns: a 3x3 matrix is a row of nine numbers, row-major, and its inverse is
its adjugate over its determinant, so no call loops over matrices one by one.

A row of :attr:`Table.f` holds position (m), velocity (m/s), position covariance (m^2) and
velocity covariance ((m/s)^2), at the columns :data:`POS`, :data:`VEL`, :data:`PCOV`,
:data:`VCOV`.
"""

from __future__ import annotations

import math

import numpy as np

from stereod.fusion.frames import ACCEL_SIGMA_MPS2, UNKNOWN_VELOCITY_SIGMA_MPS, ray_xz
from stereod.fusion.wire import CONFIRMED, EXTRA, STATIONARY, TENTATIVE, RigWire

POS, VEL, PCOV, VCOV = slice(0, 3), slice(3, 6), slice(6, 15), slice(15, 24)
WIDTH = 24
SEEN, MOVING, VVALID, HVALID = range(4)
"""Columns of :attr:`Table.flags`: measured in this pair, measured and not stationary,
velocity valid, heading valid."""
_SEEN_MOVING = np.zeros((4, 2), dtype=bool)
_SEEN_MOVING[CONFIRMED] = True, True
_SEEN_MOVING[STATIONARY] = True, False
"""By lifecycle code, the :data:`SEEN` and :data:`MOVING` flags."""
DIAG = np.array([0, 4, 8])
"""The diagonal's columns in a row-major 3x3 matrix of nine columns."""
DIAG_P = np.array([6, 10, 14])
"""The position covariance's diagonal among a table row's columns."""
TRANSPOSE = np.array([0, 3, 6, 1, 4, 7, 2, 5, 8])
# inv = adj / det, adj[k] = m[P[k]] m[Q[k]] - m[R[k]] m[S[k]] (row-major 3x3): P, Q, R, S
# one after another, so that the four are one gather.
_PQRS = np.array([
    4, 2, 1, 5, 0, 2, 3, 1, 0,
    8, 7, 5, 6, 8, 3, 7, 6, 4,
    5, 1, 2, 3, 2, 0, 4, 0, 1,
    7, 8, 4, 8, 6, 5, 6, 7, 3,
])  # fmt: skip


def inv3(m: np.ndarray) -> np.ndarray:
    """The inverses of (n, 9) row-major 3x3 matrices, (n, 9): adjugate over determinant,
    worked on the transpose (each of the nine entries one contiguous run of n numbers)."""
    t = m.T
    g = t.take(_PQRS, axis=0)
    adj = g[0:9] * g[9:18] - g[18:27] * g[27:36]
    det = t[0] * adj[0] + t[1] * adj[3] + t[2] * adj[6]
    return (adj / det).T


def matvec3(m: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``M x`` for (n, 9) row-major matrices and (n, 3) vectors, (n, 3)."""
    return (m.reshape(-1, 3, 3) @ x[:, :, None])[:, :, 0]


_ACCEL_V = np.zeros(9)
_ACCEL_V[[0, 4, 8]] = ACCEL_SIGMA_MPS2**2
_ACCEL_P = _ACCEL_V / 4.0


def predict_rows(f: np.ndarray, dt_s: np.ndarray) -> np.ndarray:
    """Rows of :data:`WIDTH` columns predicted by ``dt_s`` (n,) seconds each: constant velocity,
    the velocity's uncertainty and a white acceleration of ``ACCEL_SIGMA_MPS2`` growing the
    position's covariance by dt^2 V + (a dt^2 / 2)^2 and the velocity's by (a dt)^2, as
    ``frames.predict`` does for one (each block of columns in a few whole-array operations)."""
    dt = dt_s[:, None]
    dt2 = dt * dt
    out = f.copy()
    out[:, POS] += dt * f[:, VEL]
    out[:, PCOV] += dt2 * (f[:, VCOV] + dt2 * _ACCEL_P)
    out[:, VCOV] += dt2 * _ACCEL_V
    return out


def fuse_groups(
    means: np.ndarray, covs: np.ndarray, starts: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Information-form fusion of consecutive runs of rows: ``means`` (n, 3), ``covs`` (n, 9),
    run ``g`` from ``starts[g]`` to the next start (every run at least one row). Returns each
    run's mean (k, 3) and covariance (k, 9): ``C = (sum C_i^-1)^-1`` (made symmetric),
    ``x = C sum C_i^-1 x_i``."""
    info = inv3(covs)
    both = np.empty((len(means), 12))
    both[:, :9] = info
    np.matmul(info.reshape(-1, 3, 3), means[:, :, None], out=both[:, 9:, None])
    total = np.add.reduceat(both, starts, axis=0) if len(starts) < len(means) else both
    c = inv3(total[:, :9])
    mean = matvec3(c, total[:, 9:])
    return mean, 0.5 * (c + c[:, TRANSPOSE])


def fuse_states(f: np.ndarray, starts: np.ndarray, info: np.ndarray | None = None) -> np.ndarray:
    """:func:`fuse_groups` of position and velocity at once, on rows of :data:`WIDTH` columns:
    ``f`` (n, WIDTH), run ``g`` from ``starts[g]`` to the next start; returns each run's fused
    row (k, WIDTH). A row's position and velocity are two consecutive 3-vectors, and their
    covariances two consecutive 3x3 matrices, so both are one stacked operation of 2n rows
    with no copy into separate position and velocity arrays. ``info``: those 2n covariances'
    inverses (:func:`both_inverses`), when the caller has them."""
    n = len(f)
    means = f[:, POS.start : VEL.stop].reshape(2 * n, 3)
    if info is None:
        info = both_inverses(f)
    both = np.empty((2 * n, 12))
    both[:, :9] = info
    np.matmul(info.reshape(-1, 3, 3), means[:, :, None], out=both[:, 9:, None])
    if len(starts) < n:
        both = np.add.reduceat(both.reshape(n, 24), starts, axis=0).reshape(-1, 12)
    c = inv3(both[:, :9])
    out = np.empty((len(starts), WIDTH))
    out[:, POS.start : VEL.stop] = matvec3(c, both[:, 9:]).reshape(-1, 6)
    out[:, PCOV.start : VCOV.stop] = (0.5 * (c + c[:, TRANSPOSE])).reshape(-1, 18)
    return out


def fuse_ray(
    f: np.ndarray,
    ray: np.ndarray,
    starts: np.ndarray,
    strain: np.ndarray,
    size: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`fuse_states` of predicted rows ``f`` (n, WIDTH) with each position weighed by its
    covariance along its viewing ray: the published one plus ``ray`` (n, 9) (:attr:`Table.ray`;
    prediction grows both alike), scaled by :func:`strain_scale` of the row's ``strain`` (n,)
    so far (velocity keeps its published covariance). A run of one row is that row, as
    published. Returns each run's fused row (k, WIDTH) and each row's squared Mahalanobis
    distance to its run's fused position under its own unscaled covariance along its ray (n,)
    (what :func:`strain_step` moves its strain towards; 0 for a run of one). ``size``: each
    run's length (k,), when the caller has them (:func:`run_sizes`)."""
    if len(starts) == len(f):  # every run one row
        return f[starts], np.zeros(len(f))
    if size is None:
        size = run_sizes(starts, len(f))
    alone = size == 1
    g = f.copy()
    g[:, PCOV] += ray
    both = both_inverses(g)
    info = both[0::2]  # the positions' (each row's inverse is its own: they are elementwise)
    if np.maximum.reduce(strain) > STRAIN_FREE:  # else every scale is 1
        g[:, PCOV] *= strain_scale(strain)[:, None]
        out = fuse_states(g, starts)
    else:
        out = fuse_states(g, starts, both)
    out[alone] = f[starts[alone]]
    d = f[:, POS] - out[:, POS].repeat(size, axis=0)
    return out, np.einsum("ni,ni->n", d, matvec3(info, d))


def both_inverses(f: np.ndarray) -> np.ndarray:
    """The inverses of rows ``f``'s (n, WIDTH) position and velocity covariances, (2n, 9):
    row 2i row i's position's, row 2i + 1 its velocity's."""
    return inv3(f[:, PCOV.start : VCOV.stop].reshape(2 * len(f), 9))


def run_sizes(starts: np.ndarray, n: int) -> np.ndarray:
    """The length of each run of rows from ``starts[g]`` to the next start (the last to
    ``n``), (k,): numpy's own calls, no Python wrapper."""
    size = np.empty_like(starts)
    np.subtract(starts[1:], starts[:-1], out=size[:-1])
    size[-1] = n - starts[-1]
    return size


STRAIN_TAU_S = 0.2
"""Time constant of a member's strain (:func:`strain_step`), s: a few frames."""
STRAIN_FREE = 6.0
"""A member's strain up to which it keeps its own covariance, dimensionless: four times the
mean share of a pair's 3 degrees of freedom, which an average over a few frames of a member
that agrees with the room stays under."""
STRAIN_POWER = 8
"""How steeply a strained member fades (:func:`strain_scale`): its covariance grows as its
strain over :data:`STRAIN_FREE` to this power."""
STRAIN_SCALE_MAX = 1e8
"""The most a member's covariance is scaled by (its weight 1e-8 of its own: out of the fusion,
with the inverses still well conditioned)."""


def strain_step(strain: list[float], nis: list[float], dt_s: float) -> list[float]:
    """One room track's members' strains moved on by ``dt_s`` seconds (none for a negative
    one) towards their latest squared Mahalanobis distances ``nis`` (:func:`fuse_ray`): an
    exponential average over :data:`STRAIN_TAU_S` (plain floats: a track has a few members,
    where a numpy call apiece would cost more than the arithmetic)."""
    a = -math.expm1(-max(dt_s, 0.0) / STRAIN_TAU_S)
    return [s + a * (d - s) for s, d in zip(strain, nis, strict=True)]


def strain_steps(strain: np.ndarray, nis: np.ndarray, dt_s: np.ndarray) -> np.ndarray:
    """:func:`strain_step` of many members at once, each by its own ``dt_s`` (n,) seconds:
    their strains (n,) moved towards their squared Mahalanobis distances ``nis`` (n,)."""
    a = -np.expm1(-np.maximum(dt_s, 0.0) / STRAIN_TAU_S)
    return strain + a * (nis - strain)


def without_rig(strain: dict[tuple[str, int], float], rig: str) -> dict[tuple[str, int], float]:
    """A room track's strains by (rig, track id) less ``rig``'s member (a new dict: a track's
    strains are replaced, never written into)."""
    return {k: v for k, v in strain.items() if k[0] != rig} if strain else strain


def strain_scale(strain: np.ndarray) -> np.ndarray:
    """The factor (n,) each member's position covariance is scaled by for its strain (n,): 1
    up to :data:`STRAIN_FREE`, then ``(strain / STRAIN_FREE) ** STRAIN_POWER`` (at most
    :data:`STRAIN_SCALE_MAX`). A member the room keeps contradicting (a merged blob, a stretch
    biased along its ray) fades out of its fusion within a few frames, and its distance to the
    others' fused position then keeps it out until it agrees again; one that strays for a
    frame stays in."""
    over = np.maximum(strain * (1.0 / STRAIN_FREE), 1.0)
    return np.minimum(over**STRAIN_POWER, STRAIN_SCALE_MAX)


def fuse_gaussians(
    means: list[np.ndarray], covs: list[np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """The information-form fusion of independent Gaussian estimates of one quantity: the
    covariance ``(sum C_i^-1)^-1`` and mean ``C sum C_i^-1 m_i``."""
    if len(means) == 1:
        return means[0].copy(), covs[0].copy()
    infos = [np.linalg.inv(c) for c in covs]
    cov = np.linalg.inv(np.sum(infos, axis=0))
    mean = cov @ np.sum([i @ m for i, m in zip(infos, means, strict=True)], axis=0)
    return mean, 0.5 * (cov + cov.T)


def mahalanobis2(a: np.ndarray, a_cov: np.ndarray, b: np.ndarray, b_cov: np.ndarray) -> float:
    """Squared Mahalanobis distance between two independent Gaussian positions."""
    d = a - b
    return float(d @ np.linalg.solve(a_cov + b_cov, d))


def gate_d2(x: np.ndarray, x_cov: np.ndarray, m: np.ndarray, m_cov: np.ndarray) -> np.ndarray:
    """Squared Mahalanobis distances of pairs of independent positions, (n,): ``x`` and ``m``
    (n, 3), their covariances (n, 9)."""
    d = x - m
    return np.einsum("ni,ni->n", d, matvec3(inv3(x_cov + m_cov), d))


def reach(
    x: np.ndarray, x_trace: np.ndarray, m: np.ndarray, m_trace: np.ndarray, gate: float
) -> np.ndarray:
    """Which pairs of ``x`` (a, 3) and ``m`` (b, 3) might be within ``gate`` of each other,
    (a, b) bool, from positions and covariance traces alone: ``d^T S^-1 d >= |d|^2 /
    lambda_max(S)`` and ``lambda_max(S) <= trace(S)``, so a pair whose squared distance
    exceeds ``gate`` times its traces' sum is out of the gate (a spatial bound: far pairs
    need no inverse). The bound is taken a millionth wider against rounding."""
    d = x[:, None, :] - m[None, :, :]
    return np.einsum("abi,abi->ab", d, d) <= (gate * (1.0 + 1e-6)) * (
        x_trace[:, None] + m_trace[None, :]
    )


class Table:
    """Rows of every rig's latest message, each rig in its own block of consecutive rows
    (block ``k`` from ``k * capacity``), so that any rows of any rigs are one gather."""

    def __init__(self, capacity: int = 32) -> None:
        self.capacity = capacity
        self.blocks: dict[str, int] = {}
        """Rig name -> its block."""
        self.count: dict[str, int] = {}
        """Rig name -> rows of its latest message."""
        self.f = np.zeros((0, WIDTH))
        self.stamps = np.zeros(0, dtype=np.int64)
        """Each row's UTC stamp, ns."""
        self.flags = np.zeros((0, 4), dtype=bool)
        self.extra = np.zeros((0, len(EXTRA)))
        self.ray = np.zeros((0, 9))
        """What each row's position covariance along its viewing ray (``frames.ray_cov``) adds
        to its published one, in the room frame, row-major, m^2 (:func:`fuse_ray`)."""
        self.ids: dict[str, list[int]] = {}
        """Rig name -> its rows' track ids, in row order."""
        self.index: dict[str, dict[int, int]] = {}
        """Rig name -> track id -> its row in the table."""
        self._spreads: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def _grow(self, blocks: int, capacity: int) -> None:
        """Make room for ``blocks`` blocks of ``capacity`` rows, keeping every rig's rows."""
        old = (self.f, self.stamps, self.flags, self.extra, self.capacity)
        ray = self.ray
        n = blocks * capacity
        self.ray = np.zeros((n, 9))
        self.f = np.zeros((n, WIDTH))
        self.stamps = np.zeros(n, dtype=np.int64)
        self.flags = np.zeros((n, 4), dtype=bool)
        self.extra = np.zeros((n, len(EXTRA)))
        f, stamps, flags, extra, cap = old
        for rig, k in self.blocks.items():
            a, b, c = k * cap, k * capacity, self.count.get(rig, 0)
            self.f[b : b + c], self.stamps[b : b + c] = f[a : a + c], stamps[a : a + c]
            self.flags[b : b + c], self.extra[b : b + c] = flags[a : a + c], extra[a : a + c]
            self.ray[b : b + c] = ray[a : a + c]
        self.capacity = capacity
        self.index = {
            rig: {tid: self.blocks[rig] * capacity + i for i, tid in enumerate(ids)}
            for rig, ids in self.ids.items()
        }

    def put(self, wire: RigWire, rotation: np.ndarray, translation: np.ndarray) -> None:
        """Rig ``wire.rig``'s message, its not tentative objects moved into the room frame
        (``p' = R p + t``, ``v' = R v``, ``P' = R P R^T``; a missing or non-finite sigma as
        ``frames.to_room`` takes it), in place of that rig's previous rows; :attr:`ray` what
        the position's covariance along its viewing ray (``frames.ray_cov``) adds to that."""
        tentative = wire.state == TENTATIVE
        w = wire if not np.logical_or.reduce(tentative) else wire.select(~tentative)
        n = len(w.ids)
        rig = w.rig
        if rig not in self.blocks:
            self.blocks[rig] = len(self.blocks)
        blocks = len(self.blocks)
        if n > self.capacity or blocks * self.capacity > len(self.f):
            self._grow(max(blocks, 2 * len(self.f) // max(self.capacity, 1)),
                       max(self.capacity, 2 * n))  # fmt: skip
        base = self.blocks[rig] * self.capacity
        ps, vs = w.position_sigma, w.velocity_sigma
        sig = np.concatenate([ps, vs])
        if not np.logical_and.reduce(np.isfinite(sig), axis=None):
            sig[:n] = np.where(np.isfinite(ps), ps, 1.0)
            sig[n:] = np.where(np.isfinite(vs), vs, UNKNOWN_VELOCITY_SIGMA_MPS)
        r = rotation
        rows = self.f[base : base + n]
        rows[:, POS] = w.position @ r.T + translation
        rows[:, VEL] = w.velocity @ r.T
        spread, xz = self._spread(rig, r)
        covs = np.square(sig) @ spread
        rows[:, PCOV], rows[:, VCOV] = covs[:n], covs[n:]
        self.ray[base : base + n] = ray_xz(w.position, sig[:n])[:, None] * xz
        self.stamps[base : base + n] = w.stamps_ns
        flags = self.flags[base : base + n]
        flags[:, SEEN : MOVING + 1] = _SEEN_MOVING[w.state]
        flags[:, VVALID], flags[:, HVALID] = w.velocity_valid, w.heading_valid
        self.extra[base : base + n] = w.extra
        ids = w.ids.tolist()
        self.ids[rig] = ids
        self.count[rig] = n
        self.index[rig] = dict(zip(ids, range(base, base + n), strict=True))

    def _spread(self, rig: str, rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(3, 9): squared sigmas (n, 3) times this are ``R diag(s^2) R^T`` row-major (entry
        (i, j) is ``sum_k R_ik R_jk s_k^2``, linear in s^2); and (9,): an X-Z covariance c
        times this is ``R C R^T`` of it, ``c (R_x R_z^T + R_z R_x^T)`` (``R_x``, ``R_z`` R's
        columns), row-major. Kept per rig while its rotation is the same array."""
        known = self._spreads.get(rig)
        if known is not None and known[0] is rotation:
            return known[1], known[2]
        spread = (rotation[:, None, :] * rotation[None, :, :]).reshape(9, 3).T.copy()
        xz = np.outer(rotation[:, 0], rotation[:, 2])
        self._spreads[rig] = (rotation, spread, (xz + xz.T).ravel())
        return spread, self._spreads[rig][2]

    def drop(self, rig: str) -> None:
        """Forget ``rig``'s rows (its block stays its own)."""
        self.count.pop(rig, None)
        self.ids.pop(rig, None)
        self.index.pop(rig, None)

    def rows(self, rig: str) -> range:
        """``rig``'s rows in the table (empty when it has none)."""
        if rig not in self.count:
            return range(0)
        base = self.blocks[rig] * self.capacity
        return range(base, base + self.count[rig])


class Estimates:
    """Room tracks' positions and covariances at one instant, as arrays by slot (the step's
    association works on them; a link or a new room track updates one in place)."""

    def __init__(self, rids: list[int], mean: np.ndarray, cov: np.ndarray) -> None:
        self.rids = rids
        self.slot = {rid: k for k, rid in enumerate(rids)}
        self.mean = mean
        """(k, 3) m."""
        self.cov = cov
        """(k, 9) m^2, row-major."""

    def set(self, rid: int, mean: np.ndarray, cov: np.ndarray) -> None:
        """Room track ``rid``'s estimate is now ``mean`` (3,), ``cov`` (9,)."""
        k = self.slot.get(rid)
        if k is None:
            self.slot[rid] = len(self.rids)
            self.rids.append(rid)
            self.mean = np.concatenate([self.mean, mean[None]])
            self.cov = np.concatenate([self.cov, cov[None]])
        else:
            self.mean[k], self.cov[k] = mean, cov
