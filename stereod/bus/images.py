"""Images on the bus, on demand: each eye, the foreground masks and the annotated overlay as
JPEG under ``<prefix>/<rig>/image/{left,right,overlay,mask}``.

The cost rules: nothing is drawn or encoded unless someone subscribes to that image's key
(each key's publisher has a matching listener); at most ``rate_hz`` pairs a second are
pictured; and a pair is never delayed or dropped for an image. The pipeline thread only keeps
references to the pair's frames and masks (no copy) while some image is wanted; the output
thread offers each published pair here, which costs a clock read when it is not yet time for
the next picture; drawing and encoding happen on this module's own thread, fed by a
one-place queue that drops the older picture when the encoder is still busy.

::

    pipeline thread --Outgoing (+ PairImages refs)--> output thread --offer()--> [1, drop oldest]
                                                                                    |
                                                       image thread: draw, encode, put (DROP,
                                                       DATA_LOW), ImageInfo as the attachment

Each image's attachment (:class:`~stereod.bus.messages.ImageInfo`, JSON) carries its pair's
``seq`` and ``t_ns``, so a client joins it to the ``objects`` message of the same pair.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import zenoh

from stereod.bus import keys
from stereod.bus.messages import IMAGE_ENCODING, ImageInfo, ObjectsMessage, dump
from stereod.daemon.processing import Outgoing
from stereod.daemon.status import Health
from stereod.sources.queues import BoundedQueue, Closed
from stereod.view import overlay

log = logging.getLogger(__name__)

ERROR_IMAGE = "image_error"
"""Drawing or encoding one pair's images failed; that picture was skipped."""


class ImagePublishers:
    """The four image publishers of one rig on a session, and who listens to each.

    ``wanted(name)`` says whether some subscriber matches that image's key right now (kept by a
    matching listener per key, so asking costs nothing)."""

    def __init__(self, session: zenoh.Session, rig: str, *, prefix: str) -> None:
        self.rig = rig
        self._pubs: dict[str, zenoh.Publisher] = {}
        self._wanted: dict[str, bool] = {}
        self._entities: list[Any] = []
        for name in keys.IMAGES:
            pub = session.declare_publisher(
                keys.image(name, rig, prefix=prefix),
                encoding=zenoh.Encoding(IMAGE_ENCODING),
                congestion_control=zenoh.CongestionControl.DROP,
                priority=zenoh.Priority.DATA_LOW,
            )
            self._pubs[name] = pub
            self._entities.append(pub.declare_matching_listener(self._listener(name)))
            # The stub says bool; at runtime it is a MatchingStatus.
            self._wanted[name] = bool(pub.matching_status.matching)  # type: ignore[attr-defined]

    def _listener(self, name: str) -> Callable[[zenoh.MatchingStatus], None]:
        def on_matching(status: zenoh.MatchingStatus) -> None:
            self._wanted[name] = bool(status.matching)
            log.info("image %s: %s", name, "subscribed" if status.matching else "unsubscribed")

        return on_matching

    def wanted(self, name: str) -> bool:
        return self._wanted.get(name, False)

    def any_wanted(self) -> bool:
        """Whether any image key has a subscriber."""
        return any(self._wanted.values())

    def put(self, name: str, jpeg: bytes, info: ImageInfo) -> None:
        self._pubs[name].put(jpeg, attachment=dump(info))

    def close(self) -> None:
        for e in self._entities:
            e.undeclare()
        self._entities.clear()
        for pub in self._pubs.values():
            pub.undeclare()
        self._pubs.clear()
        self._wanted.clear()


class ImageWorker:
    """Draws, encodes and publishes the images of at most ``rate_hz`` pairs a second
    (thread target: :meth:`loop`; the output thread calls :meth:`offer`).

    ``quality`` is the JPEG quality (1-100). Counters: ``encoded`` images published by name,
    ``skipped`` pictures replaced in the queue before the encoder got to them, ``failed``
    pictures whose drawing or encoding raised (each one counted on the status key's errors)."""

    def __init__(
        self,
        publishers: ImagePublishers,
        health: Health,
        *,
        rate_hz: float,
        quality: int = 80,
    ) -> None:
        self.publishers = publishers
        self.health = health
        self.period_s = 1.0 / rate_hz if rate_hz > 0 else float("inf")
        self.quality = quality
        self._queue: BoundedQueue[Outgoing] = BoundedQueue(1, drop_oldest=True)
        self._next_s = 0.0
        self.encoded: dict[str, int] = dict.fromkeys(keys.IMAGES, 0)
        self.failed = 0
        self.encode_s = 0.0
        """Time spent drawing and encoding (s, wall clock), for the benchmark."""

    @property
    def skipped(self) -> int:
        return self._queue.dropped

    def wanted(self) -> bool:
        """Whether the pipeline should keep its frames for images (some image is subscribed)."""
        return self.period_s != float("inf") and self.publishers.any_wanted()

    def offer(self, item: Outgoing) -> None:
        """Picture this pair if some image is wanted and it is time (any thread; never
        blocks: a picture still waiting for the encoder is replaced by this one)."""
        if item.message is None or item.images is None:
            return
        now = time.monotonic()
        if now < self._next_s:
            return
        self._next_s = now + self.period_s
        self._queue.put(item)

    def close(self) -> None:
        """No more offers; the thread finishes what is queued and ends."""
        self._queue.close()

    def loop(self) -> None:
        while True:
            try:
                item = self._queue.get(timeout=0.25)
            except Closed:
                return
            if item is None:
                continue
            try:
                self.publish(item)
            except Exception as exc:  # a picture must never stop the daemon
                self.failed += 1
                self.health.error(ERROR_IMAGE)
                self.health.problem(f"images: drawing or encoding failed: {exc}", ERROR_IMAGE)
                log.debug("image of pair failed", exc_info=True)

    def publish(self, item: Outgoing) -> None:
        """Draw, encode and put every wanted image of one pair."""
        msg, images, result = item.message, item.images, item.result
        assert msg is not None and images is not None and result is not None
        t0 = time.perf_counter()
        pubs = self.publishers
        for name in keys.IMAGES:
            if not pubs.wanted(name):
                continue
            if name == "left":
                picture = images.left
            elif name == "right":
                picture = images.right
            elif name == "mask":
                picture = overlay.masks(images)
            else:
                picture = overlay.overlay(
                    images,
                    overlay.Annotations(
                        msg.seq, msg.t_ns, msg.skew_ns, result.left, result.right, result.tracks
                    ),
                )
            data = overlay.jpeg(picture, self.quality)
            pubs.put(name, data, _info(msg, name, picture, pubs.rig))
            self.encoded[name] += 1
        self.encode_s += time.perf_counter() - t0


def _info(msg: ObjectsMessage, name: str, picture: np.ndarray, rig: str) -> ImageInfo:
    return ImageInfo(
        rig=rig,
        name=name,
        seq=msg.seq,
        t_ns=msg.t_ns,
        stamp_utc_ns=msg.stamp_utc_ns,
        width=int(picture.shape[1]),
        height=int(picture.shape[0]),
    )
