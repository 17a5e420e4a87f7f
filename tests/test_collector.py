"""The start-up heap frozen: a full collection afterwards walks only what was made since."""

from __future__ import annotations

import gc

from stereod.fusion.collector import freeze_startup_heap


def test_the_start_up_heap_is_left_out_of_later_collections() -> None:
    try:
        frozen = freeze_startup_heap()
        assert frozen == gc.get_freeze_count() > 10_000  # pytest, numpy and stereod imported
        made = [[k] for k in range(1000)]  # containers made after start-up
        assert sum(len(gc.get_objects(g)) for g in range(3)) < frozen
        assert any(o is made for o in gc.get_objects())
    finally:
        gc.unfreeze()
    assert gc.get_freeze_count() == 0
