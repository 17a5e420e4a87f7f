"""The start-up heap frozen: garbage left by start-up is collected first, and a full
collection afterwards walks only what was made since."""

from __future__ import annotations

import gc
import weakref

import pytest

from stereod.fusion.collector import freeze_startup_heap


class _Node:
    """A container that can hold itself in a cycle (only the collector frees it)."""

    other: object = None


def test_start_up_garbage_is_freed_and_the_rest_left_out_of_later_collections() -> None:
    if gc.get_freeze_count():
        pytest.skip("something in this process froze its heap already")
    cycle = _Node()
    cycle.other = cycle
    gone = weakref.ref(cycle)
    del cycle
    try:
        frozen = freeze_startup_heap()
        assert gone() is None  # collected before the freeze, not frozen for ever
        assert frozen > 10_000  # pytest, numpy and stereod imported
        # as frozen, less any that another thread of this process freed since (a frozen
        # object is still freed when its last reference goes)
        assert frozen - 100 <= gc.get_freeze_count() <= frozen
        made = [[k] for k in range(1000)]  # containers made after start-up
        assert sum(len(gc.get_objects(g)) for g in range(3)) < frozen
        assert any(o is made for o in gc.get_objects())
    finally:
        gc.unfreeze()
    assert gc.get_freeze_count() == 0
