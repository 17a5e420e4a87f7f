"""Bounded queues: drop-oldest for live sources, blocking for files, drain on close."""

from __future__ import annotations

import threading

import pytest

from stereod.sources.queues import BoundedQueue, Closed


def test_drop_oldest_keeps_newest_and_counts() -> None:
    q: BoundedQueue[int] = BoundedQueue(3, drop_oldest=True)
    for i in range(10):
        assert q.put(i)
    assert len(q) == 3 and q.dropped == 7
    assert [q.get(0), q.get(0), q.get(0)] == [7, 8, 9]


def test_blocking_queue_loses_nothing() -> None:
    q: BoundedQueue[int] = BoundedQueue(2, drop_oldest=False)
    got: list[int] = []

    def consume() -> None:
        while True:
            try:
                item = q.get(0.5)
            except Closed:
                return
            if item is not None:
                got.append(item)

    t = threading.Thread(target=consume)
    t.start()
    for i in range(500):
        assert q.put(i)
    q.close()
    t.join(5)
    assert got == list(range(500)) and q.dropped == 0 and q.high_water <= 2


def test_blocked_put_gives_up_on_stop() -> None:
    q: BoundedQueue[int] = BoundedQueue(1, drop_oldest=False)
    q.put(1)
    stop = threading.Event()
    stop.set()
    assert q.put(2, stop) is False


def test_closed_queue_drains_then_raises() -> None:
    q: BoundedQueue[int] = BoundedQueue(4, drop_oldest=True)
    q.put(1)
    q.close()
    assert q.put(2) is False
    assert q.get(0) == 1
    with pytest.raises(Closed):
        q.get(0)
    with pytest.raises(ValueError):
        BoundedQueue(0, drop_oldest=True)


def test_put_if_empty_never_displaces_or_waits() -> None:
    """What is worth having only while the consumer is idle goes in only when nothing waits."""
    q: BoundedQueue[int] = BoundedQueue(1, drop_oldest=True)
    assert q.put_if_empty(1)
    assert not q.put_if_empty(2)
    assert q.get(0) == 1 and q.dropped == 0
    assert q.put_if_empty(7) and q.get(0) == 7  # taken: what comes next is no longer expendable
    assert q.put(8) and q.put(9)
    assert q.dropped == 1 and q.get(0) == 9
    assert q.put_if_empty(4)
    assert q.put(5)  # full: the expendable item goes, uncounted
    assert q.dropped == 1
    assert q.put(6)  # full of a real item: dropped and counted
    assert q.dropped == 2 and q.get(0) == 6
    q.close()
    assert not q.put_if_empty(3)
