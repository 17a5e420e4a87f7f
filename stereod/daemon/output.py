"""The output thread: sends each pair's payloads over Zenoh and, when asked, to a JSONL file.

Publishing never blocks (Zenoh puts use congestion DROP). A live source's JSONL is written by
a thread of its own from a queue that drops its oldest line when full (``jsonl_behind``): a
pipe's reader that reads slowly gets what it can take, and never holds back the Zenoh
messages; a file source's is written in turn, waiting for its reader. A JSONL write that
fails (a full disk) ends the run with :class:`~stereod.errors.OutputError` (exit 73); the
thread keeps draining its queue so the pipeline is never left blocked behind it. A JSONL
written into a pipe whose reader closed it, or took nothing for ``JSONL_STALL_S``
(:class:`~stereod.errors.ReaderGone`), goes to ``on_reader_gone``: a replay ends, a daemon
stops writing it and says so on its status key.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

from stereod.bus.publish import Publisher
from stereod.daemon.processing import Outgoing
from stereod.daemon.status import Health
from stereod.errors import OutputError, ReaderGone
from stereod.files.output_file import AtomicOutput
from stereod.sources.queues import BoundedQueue, Closed

log = logging.getLogger(__name__)

JSONL_QUEUE = 64
"""Lines a live daemon's JSONL may hold waiting for its reader (about 2 s at 30 Hz); the
oldest is dropped beyond it."""
DROP_JSONL_BEHIND = "jsonl_behind"
"""A JSONL line waited too long for its reader and a newer one replaced it (live sources)."""


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
        live: bool = False,
    ) -> None:
        self.out = out
        self.publisher = publisher
        self.health = health
        self.jsonl = jsonl
        self._on_fatal = on_fatal
        self._on_message = on_message
        self._on_reader_gone = on_reader_gone or on_fatal
        self._lines: BoundedQueue[bytes] | None = None
        if live and jsonl is not None:
            self._lines = BoundedQueue(JSONL_QUEUE, drop_oldest=True)
            health.watch_queue(DROP_JSONL_BEHIND, self._lines)

    def loop(self) -> None:
        writer = None
        if self._lines is not None:
            writer = threading.Thread(target=self._write_loop, name="jsonl", daemon=True)
            writer.start()
        try:
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
        finally:
            if writer is not None and self._lines is not None:
                self._lines.close()  # what is queued is written (a stop bounds each wait)
                writer.join()

    def _write_loop(self) -> None:
        """The JSONL thread's loop (live sources): write each line queued, in order."""
        assert self._lines is not None
        try:
            while True:
                try:
                    line = self._lines.get(timeout=0.25)
                except Closed:
                    break
                if line is not None:
                    self.health.busy("jsonl")  # a write that hangs (a dead disk) is stuck
                    try:
                        self._write(line)
                    finally:
                        self.health.idle("jsonl")
        except BaseException as exc:  # no thread dies silently
            self._on_fatal(exc)

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
        if self._lines is not None:
            self._lines.put(item.payload + b"\n")
        else:
            self._write(item.payload + b"\n")

    def _write(self, line: bytes) -> None:
        """Write one line to the JSONL (if it is still written)."""
        if self.jsonl is not None:
            try:
                self.jsonl.write(line)
                if self.jsonl.in_place:  # a pipe or terminal gets each message as it comes
                    self.jsonl.flush()
            except OutputError as exc:
                self.jsonl.discard()
                self.jsonl = None
                if isinstance(exc, ReaderGone):
                    self._on_reader_gone(exc)
                else:
                    self._on_fatal(exc)
