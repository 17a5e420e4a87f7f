"""The output thread: sends each pair's payloads over Zenoh and, when asked, to a JSONL file.

Publishing never blocks (Zenoh puts use congestion DROP). A JSONL write that fails (a full
disk) ends the run with :class:`~stereod.errors.OutputError` (exit 73); the thread keeps
draining its queue so the pipeline is never left blocked behind it. A JSONL written into a
pipe whose reader closed it (:class:`~stereod.errors.ReaderGone`) goes to ``on_reader_gone``:
a replay ends, a daemon stops writing it and says so on its status key.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

from stereod.bus.publish import Publisher
from stereod.daemon.processing import Outgoing
from stereod.daemon.status import Health
from stereod.errors import OutputError, ReaderGone
from stereod.files.output_file import AtomicOutput
from stereod.sources.queues import BoundedQueue, Closed

log = logging.getLogger(__name__)


class Output:
    """Drains the outgoing queue of one run (thread target: :meth:`loop`)."""

    def __init__(
        self,
        out: BoundedQueue[Outgoing],
        publisher: Publisher,
        health: Health,
        *,
        jsonl: AtomicOutput | None,
        on_fatal: Callable[[BaseException], None],
        on_message: Callable[[Outgoing], None] | None = None,
        on_reader_gone: Callable[[ReaderGone], None] | None = None,
    ) -> None:
        self.out = out
        self.publisher = publisher
        self.health = health
        self.jsonl = jsonl
        self._on_fatal = on_fatal
        self._on_message = on_message
        self._on_reader_gone = on_reader_gone or on_fatal

    def loop(self) -> None:
        while True:
            try:
                item = self.out.get(timeout=0.25)
            except Closed:
                break
            if item is None:
                continue
            self.health.busy("output")
            try:
                self._send(item)
            finally:
                self.health.idle("output")

    def _send(self, item: Outgoing) -> None:
        """Publish one item, hand it on, and write it to the JSONL."""
        if item.message is None:
            self.publisher.objects_end(item.ended)
            return
        self.publisher.objects(item.payload, item.tracks, item.ended)
        self.health.published = self.publisher.published
        self.health.publish_errors = self.publisher.errors
        if self._on_message is not None:
            self._on_message(item)
        if self.jsonl is not None:
            try:
                self.jsonl.write(item.payload + b"\n")
                if self.jsonl.in_place:  # a pipe or terminal gets each message as it comes
                    self.jsonl.flush()
            except OutputError as exc:
                self.jsonl.discard()
                self.jsonl = None
                if isinstance(exc, ReaderGone):
                    self._on_reader_gone(exc)
                else:
                    self._on_fatal(exc)
