"""Pairer: nearest timestamps within tolerance, every drop counted by reason."""

from __future__ import annotations

import numpy as np
import pytest

from stereod.sources.frames import Eye, Frame
from stereod.sources.pairing import (
    DROP_CLOCK_JUMP,
    DROP_NO_PARTNER,
    DROP_NON_MONOTONIC,
    DROP_OVERFLOW,
    HYSTERESIS,
    RESYNC_AFTER,
    Pairer,
)

IMG = np.zeros((2, 2), np.uint8)
MS = 1_000_000


def frames(eye: Eye, times_ns: list[int] | np.ndarray) -> list[Frame]:
    return [Frame(eye, IMG, int(t), i) for i, t in enumerate(times_ns)]


def interleave(left: list[Frame], right: list[Frame]) -> list[Frame]:
    """Arrival order: by timestamp, as two free-running cameras deliver them."""
    return sorted(left + right, key=lambda f: f.t_ns)


def run(pairer: Pairer, stream: list[Frame]) -> list[tuple[int, int]]:
    out = []
    for f in stream:
        out += pairer.push(f)
    out += pairer.flush()
    return [(p.left.seq, p.right.seq) for p in out]


def nearest_truth(left_t: np.ndarray, right_t: np.ndarray, tol: int) -> list[tuple[int, int]]:
    """Independent reference: mutual nearest neighbours within the tolerance."""
    pairs = []
    for i, t in enumerate(left_t):
        j = int(np.argmin(np.abs(right_t - t)))
        if abs(right_t[j] - t) <= tol and int(np.argmin(np.abs(left_t - right_t[j]))) == i:
            pairs.append((i, j))
    return pairs


@pytest.mark.parametrize("skew_ms", [0.0, 5.0, 16.0, -16.0, 30.0])
def test_constant_skew_pairs_every_frame_with_its_skew(skew_ms: float) -> None:
    period = 1e9 / 30
    left_t = np.arange(60) * period
    right_t = left_t + skew_ms * MS
    pairer = Pairer(tolerance_ns=20 * MS)
    pairs = []
    for f in interleave(frames(Eye.LEFT, left_t), frames(Eye.RIGHT, right_t)):
        pairs += pairer.push(f)
    pairs += pairer.flush()
    expected = nearest_truth(left_t, right_t, 20 * MS)
    assert [(p.left.seq, p.right.seq) for p in pairs] == expected
    for p in pairs:
        assert p.skew_ns == p.right.t_ns - p.left.t_ns
        assert p.t_ns == (p.left.t_ns + p.right.t_ns) // 2
    assert [p.seq for p in pairs] == list(range(len(pairs)))


def test_jittered_free_running_eyes_match_mutual_nearest() -> None:
    rng = np.random.default_rng(3)
    period = 1e9 / 15
    k = np.arange(200)
    left_t = (k * period + rng.normal(0, 2 * MS, 200)).astype(np.int64)
    right_t = (k * period + 21 * MS + rng.normal(0, 2 * MS, 200)).astype(np.int64)
    tol = 40 * MS
    pairer = Pairer(tolerance_ns=tol)
    got = run(pairer, interleave(frames(Eye.LEFT, left_t), frames(Eye.RIGHT, right_t)))
    assert got == nearest_truth(left_t, right_t, tol)
    stats = pairer.stats
    assert stats.frames[Eye.LEFT] == stats.frames[Eye.RIGHT] == 200
    assert 2 * stats.pairs + sum(stats.drops.values()) == 400


def test_drifting_clocks_keep_skew_within_half_a_period() -> None:
    """Two free-running 15 Hz eyes whose phase drifts through every offset: each frame is used
    once, in order, and no pair is further apart than half a period plus the jitter."""
    rng = np.random.default_rng(5)
    period = 1e9 / 15
    left_t = np.cumsum(period + rng.normal(0, 1 * MS, 600)).astype(np.int64)
    right_t = np.cumsum(period * 1.001 + rng.normal(0, 1 * MS, 600)).astype(np.int64)
    pairer = Pairer(tolerance_ns=int(period))
    got = run(pairer, interleave(frames(Eye.LEFT, left_t), frames(Eye.RIGHT, right_t)))
    li, ri = (np.array(x) for x in zip(*got))
    assert np.all(np.diff(li) > 0) and np.all(np.diff(ri) > 0)
    skew = np.abs(right_t[ri] - left_t[li])
    bound = (0.5 + HYSTERESIS) * period + 5 * MS
    assert skew.max() <= bound, f"max skew {skew.max() / MS:.1f} ms"
    assert len(got) >= 0.99 * 600, f"only {len(got)} of 600 frames paired"
    assert 2 * pairer.stats.pairs + sum(pairer.stats.drops.values()) == 1200


def test_dropped_frames_are_counted_and_partners_not_mismatched() -> None:
    period = 1e9 / 30
    left_t = np.arange(100) * period
    right_t = left_t + 3 * MS
    keep_right = np.ones(100, bool)
    keep_right[[10, 11, 50]] = False
    keep_left = np.ones(100, bool)
    keep_left[70] = False
    lf = [f for f, k in zip(frames(Eye.LEFT, left_t), keep_left) if k]
    rf = [f for f, k in zip(frames(Eye.RIGHT, right_t), keep_right) if k]
    pairer = Pairer(tolerance_ns=10 * MS)
    got = run(pairer, interleave(lf, rf))
    assert all(i == j for i, j in got), "a frame was paired with the wrong partner"
    assert len(got) == 96
    assert pairer.stats.drops[DROP_NO_PARTNER] == 4


def test_non_monotonic_timestamp_is_dropped_and_counted() -> None:
    pairer = Pairer(tolerance_ns=10 * MS)
    left = frames(Eye.LEFT, [0, 33 * MS, 20 * MS, 66 * MS])
    right = frames(Eye.RIGHT, [1 * MS, 34 * MS, 67 * MS])
    got = run(pairer, [left[0], right[0], left[1], right[1], left[2], left[3], right[2]])
    assert got == [(0, 0), (1, 1), (3, 2)]
    assert pairer.stats.drops[DROP_NON_MONOTONIC] == 1


@pytest.mark.parametrize("ahead_s", [5.0, 1e6])
def test_one_frame_stamped_far_ahead_costs_a_few_pairs_not_the_run(ahead_s: float) -> None:
    """Left frame 30 is stamped far in the future (a driver's glitch): the left frames after
    it are all before it, in order among themselves, so after ``RESYNC_AFTER`` of them the
    glitch is dropped and pairing goes on; every other pair is made, partners matched."""
    period = 1e9 / 30
    left_t = np.arange(100) * period
    right_t = left_t + 3 * MS
    stream = interleave(frames(Eye.LEFT, left_t), frames(Eye.RIGHT, right_t))  # as they come
    k = next(i for i, f in enumerate(stream) if f.eye is Eye.LEFT and f.seq == 30)
    stream[k] = Frame(Eye.LEFT, IMG, int(left_t[30] + ahead_s * 1e9), 30)
    pairer = Pairer(tolerance_ns=10 * MS)
    got = run(pairer, stream)
    assert all(i == j for i, j in got), "a frame was paired with the wrong partner"
    lost = set(range(100)) - {i for i, _ in got}
    assert 30 in lost and len(lost) <= RESYNC_AFTER + 2, sorted(lost)
    assert max(lost) < 30 + RESYNC_AFTER + 2
    assert pairer.stats.drops[DROP_CLOCK_JUMP] == 1
    assert pairer.stats.resyncs == {Eye.LEFT: 1, Eye.RIGHT: 0}
    # The jump left nothing in the eye's period estimate (it decides when to wait).
    assert pairer.period_ns(Eye.LEFT) == pytest.approx(period, rel=0.01)


def test_frames_out_of_order_now_and_then_do_not_resync() -> None:
    """Single late frames are dropped as before; only a stream of its own resynchronises."""
    period = 33 * MS
    t = [k * period for k in range(40)]
    for k in (10, 20, 30):
        t[k] = t[k - 2] - MS  # late: before the frame two earlier
    pairer = Pairer(tolerance_ns=10 * MS)
    run(pairer, frames(Eye.LEFT, t))
    assert pairer.stats.drops[DROP_NON_MONOTONIC] == 3
    assert pairer.stats.resyncs[Eye.LEFT] == 0


def test_stalled_eye_does_not_grow_memory() -> None:
    pairer = Pairer(tolerance_ns=10 * MS, max_pending=8)
    for f in frames(Eye.LEFT, np.arange(1000) * 33 * MS):
        assert pairer.push(f) == []
        assert pairer.pending() <= 8
    assert pairer.stats.drops[DROP_OVERFLOW] == 992


@pytest.mark.parametrize(
    ("in_order", "drops"),
    [(True, {DROP_NO_PARTNER: 20}), (False, {DROP_OVERFLOW: 12, DROP_NO_PARTNER: 8})],
)
def test_frames_of_a_file_whose_partners_are_missing_have_no_partner(
    in_order: bool, drops: dict[str, int]
) -> None:
    """The left eye lacks frames 10 to 29 (a damaged stretch of its video): in a file's time
    order, the right frames of those instants can have no partner, and are counted so, not as
    the overflow of a stalled eye (which a live source's would be: 12 of them, beyond the 8
    that may wait); every other frame pairs with its own."""
    t = np.arange(60) * 33 * MS
    left = [f for f in frames(Eye.LEFT, t) if not 10 <= f.seq < 30]
    pairer = Pairer(tolerance_ns=10 * MS, max_pending=8)
    pairer.in_order = in_order
    pairs = run(pairer, interleave(left, frames(Eye.RIGHT, t + 5 * MS)))
    assert pairs == [(k, k) for k in range(60) if not 10 <= k < 30]
    assert {k: v for k, v in pairer.stats.drops.items() if v} == drops


def test_tolerance_must_be_positive() -> None:
    with pytest.raises(ValueError, match="tolerance"):
        Pairer(tolerance_ns=0)


@pytest.mark.parametrize("jitter_ms", [0.0, 0.5])
def test_half_a_frame_of_skew_keeps_every_frame_paired(jitter_ms: float) -> None:
    """At exactly half a frame (and jittering around it) both neighbours are equally near:
    the pairing keeps its phase, so no frame is dropped and consecutive pairs use consecutive
    frames of both eyes."""
    rng = np.random.default_rng(7)
    period = 1e9 / 30
    k = np.arange(300)
    left_t = (k * period + rng.normal(0, jitter_ms * MS, 300)).astype(np.int64)
    right_t = (k * period + period / 2 + rng.normal(0, jitter_ms * MS, 300)).astype(np.int64)
    pairer = Pairer(tolerance_ns=40 * MS)
    got = run(pairer, interleave(frames(Eye.LEFT, left_t), frames(Eye.RIGHT, right_t)))
    assert len(got) >= 299, f"{300 - len(got)} frames dropped: {dict(pairer.stats.drops)}"
    offsets = {j - i for i, j in got}
    assert len(offsets) == 1, f"the pairing changed phase: {offsets}"
