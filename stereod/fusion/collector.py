"""Python's garbage collector kept off the fusion node's start-up heap.

A full collection walks every container object the process holds. After start-up that is
mostly what importing NumPy, pydantic and Zenoh made (about 50,000 objects in ``stereod
fuse``), which never becomes garbage. The fusion node makes containers fast enough (every rig
message's parsed rows, every step's payloads) that with 16 rigs a full collection came every
10 to 20 s, and walking that heap took 30 to 100 ms on a loaded 2-core host: a stall of the
fusion thread, with every rig message behind it waiting. Frozen once start-up is done, those
objects are left out of every later collection, which then walks only what the running node
made. (The rig daemon's pipeline makes almost no containers: NumPy arrays are not tracked, and
300 pairs ran without a single collection.)
"""

from __future__ import annotations

import gc


def freeze_startup_heap() -> int:
    """Collect once, then move every object still tracked into the collector's permanent
    generation (:func:`gc.freeze`); call it when start-up is done, before the hot loop. Gives
    the number of objects frozen."""
    gc.collect()
    gc.freeze()
    return gc.get_freeze_count()
