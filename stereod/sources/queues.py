"""A bounded queue that either drops its oldest item or blocks when full, and can be closed.

Live cameras cannot wait, so their queues drop the oldest item and count it (memory stays
bounded, the newest data wins); file sources can wait, so their queues block instead and
nothing is lost. Closing lets a consumer drain what is left and then see the end.
"""

from __future__ import annotations

import collections
import threading
from typing import Generic, TypeVar

T = TypeVar("T")


class Closed(Exception):
    """Raised by :meth:`BoundedQueue.get` once the queue is closed and empty."""


class BoundedQueue(Generic[T]):
    """At most ``maxsize`` items; ``drop_oldest`` chooses dropping over blocking when full."""

    def __init__(self, maxsize: int, *, drop_oldest: bool) -> None:
        if maxsize < 1:
            raise ValueError(f"queue size must be >= 1, got {maxsize}")
        self.maxsize = maxsize
        self.drop_oldest = drop_oldest
        self._items: collections.deque[T] = collections.deque()
        self._expendable = False
        """Whether the oldest item was put with :meth:`put_if_empty` (its loss is no drop)."""
        self._cond = threading.Condition()
        self._closed = False
        self.dropped = 0
        """Items dropped because the queue was full (drop_oldest only), not counting one put
        with :meth:`put_if_empty`."""
        self.high_water = 0
        """Largest depth seen."""

    def put(self, item: T, stop: threading.Event | None = None) -> bool:
        """Add ``item``; return False if it was not added (queue closed, or ``stop`` set while
        blocked)."""
        with self._cond:
            while not self.drop_oldest and len(self._items) >= self.maxsize and not self._closed:
                if stop is not None and stop.is_set():
                    return False
                self._cond.wait(0.1)
            if self._closed:
                return False
            if len(self._items) >= self.maxsize:
                self._items.popleft()
                if not self._expendable:
                    self.dropped += 1
                self._expendable = False
            self._items.append(item)
            self.high_water = max(self.high_water, len(self._items))
            self._cond.notify_all()
            return True

    def put_if_empty(self, item: T) -> bool:
        """Add ``item`` only if nothing is waiting (something worth having only when the
        consumer is idle, which never displaces or waits behind what is queued, and which a
        full queue drops first without counting it); return whether it was added."""
        with self._cond:
            if self._closed or self._items:
                return False
            self._expendable = True
            self._items.append(item)
            self._cond.notify_all()
            return True

    def get(self, timeout: float | None = None) -> T | None:
        """Next item; ``None`` on timeout; raises :class:`Closed` when closed and drained."""
        with self._cond:
            if not self._items and not self._closed:
                self._cond.wait(timeout)
            if self._items:
                item = self._items.popleft()
                self._expendable = False
                self._cond.notify_all()
                return item
            if self._closed:
                raise Closed
            return None

    def close(self) -> None:
        """No more puts; consumers drain what is left, then get :class:`Closed`."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    def __len__(self) -> int:
        with self._cond:
            return len(self._items)
