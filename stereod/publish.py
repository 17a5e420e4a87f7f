"""Everything stereod says on Zenoh (design sec. 4), behind one small class.

Keys under ``<prefix>/<rig>``: ``objects`` (one message per pair, congestion DROP, DATA_HIGH),
``objects/<track_id>`` (one publisher per live track, a DELETE when it ends), ``status``
(re-sent as soon as a subscriber appears), the ``config``, ``calibration`` and ``stats``
queryables, and the ``alive`` liveliness token, declared last so that a client that sees it can
query everything else. Publishing never blocks the pipeline: puts use congestion DROP.
"""

from __future__ import annotations

import json
import logging
import threading
from collections.abc import Callable
from types import TracebackType
from typing import Any

import zenoh

from . import keys
from .config import ZenohConfig
from .errors import ConfigError
from .messages import OBJECT_SCHEMA, OBJECTS_SCHEMA, STATUS_SCHEMA, encoding_for

log = logging.getLogger(__name__)


def session_config(cfg: ZenohConfig) -> zenoh.Config:
    """A Zenoh config from ours: mode, endpoints, and no multicast scouting unless asked."""
    zc = zenoh.Config()
    try:
        zc.insert_json5("mode", json.dumps(cfg.mode))
        zc.insert_json5(
            "scouting",
            json.dumps({"delay": 0, "multicast": {"enabled": cfg.multicast_scouting}}),
        )
        if cfg.connect:
            zc.insert_json5("connect/endpoints", json.dumps(cfg.connect))
        if cfg.listen:
            zc.insert_json5("listen/endpoints", json.dumps(cfg.listen))
    except zenoh.ZError as exc:
        raise ConfigError(f"zenoh: invalid setting: {exc}") from exc
    return zc


def open_session(cfg: ZenohConfig) -> zenoh.Session:
    """Open a session; a bad endpoint becomes a :class:`ConfigError` naming it."""
    try:
        return zenoh.open(session_config(cfg))
    except zenoh.ZError as exc:
        raise ConfigError(
            f"zenoh: cannot open a session (listen={cfg.listen}, connect={cfg.connect}): {exc}"
        ) from exc


class Publisher:
    """The daemon's Zenoh face; use as a context manager around the daemon's life."""

    def __init__(
        self,
        cfg: ZenohConfig,
        rig: str,
        queryables: dict[str, Callable[[], bytes]],
        on_status_subscriber: Callable[[], None] | None = None,
    ) -> None:
        self.rig = rig
        self.prefix = cfg.prefix
        self.base = keys.base(rig, prefix=cfg.prefix)
        self._cfg = cfg
        self._queryables = queryables
        self._on_status_subscriber = on_status_subscriber
        self._session: zenoh.Session | None = None
        self._tracks: dict[int, zenoh.Publisher] = {}
        self._entities: list[Any] = []
        self._lock = threading.Lock()
        self.published = 0
        self.errors = 0

    def open(self) -> Publisher:
        s = open_session(self._cfg)
        self._session = s
        self._objects = s.declare_publisher(
            keys.objects(self.rig, prefix=self.prefix),
            encoding=zenoh.Encoding(encoding_for(OBJECTS_SCHEMA)),
            congestion_control=zenoh.CongestionControl.DROP,
            priority=zenoh.Priority.DATA_HIGH,
        )
        self._status = s.declare_publisher(
            keys.status(self.rig, prefix=self.prefix),
            encoding=zenoh.Encoding(encoding_for(STATUS_SCHEMA)),
            congestion_control=zenoh.CongestionControl.DROP,
        )
        if self._on_status_subscriber is not None:
            self._entities.append(self._status.declare_matching_listener(self._matching))
        for name, fn in self._queryables.items():
            self._entities.append(
                s.declare_queryable(
                    keys.queryable(name, self.rig, prefix=self.prefix), self._replier(name, fn)
                )
            )
        self._alive = s.liveliness().declare_token(keys.alive(self.rig, prefix=self.prefix))
        log.info("zenoh session open, publishing under %s/", self.base)
        return self

    @property
    def session(self) -> zenoh.Session:
        """The open session (for entities declared elsewhere, e.g. the image publishers)."""
        if self._session is None:
            raise RuntimeError("the publisher is not open")
        return self._session

    def _matching(self, status: zenoh.MatchingStatus) -> None:
        if status.matching and self._on_status_subscriber is not None:
            self._on_status_subscriber()

    def _replier(self, name: str, fn: Callable[[], bytes]) -> Callable[[zenoh.Query], None]:
        key = keys.queryable(name, self.rig, prefix=self.prefix)

        def reply(query: zenoh.Query) -> None:
            with query:
                try:
                    query.reply(key, fn(), encoding=zenoh.Encoding("application/json"))
                except Exception as exc:  # a queryable must answer, never kill the session
                    log.warning("query on %s failed: %s", key, exc)
                    query.reply_err(str(exc))

        return reply

    def objects(self, payload: bytes, tracks: list[tuple[int, bytes]], ended: list[int]) -> None:
        """Publish one pair's message, each live track's state and a DELETE per ended track."""
        with self._lock:
            try:
                self._objects.put(payload)
                for tid, body in tracks:
                    pub = self._tracks.get(tid)
                    if pub is None:
                        assert self._session is not None
                        pub = self._session.declare_publisher(
                            keys.track(self.rig, tid, prefix=self.prefix),
                            encoding=zenoh.Encoding(encoding_for(OBJECT_SCHEMA)),
                            congestion_control=zenoh.CongestionControl.DROP,
                        )
                        self._tracks[tid] = pub
                    pub.put(body)
                for tid in ended:
                    self._end_track(tid)
                self.published += 1
            except zenoh.ZError as exc:
                self.errors += 1
                log.warning("publish failed: %s", exc)

    def objects_end(self, ended: list[int]) -> None:
        """A DELETE on each ended track's key, with no objects message (end of input)."""
        with self._lock:
            for tid in ended:
                self._end_track(tid)

    def has_objects_subscriber(self) -> bool:
        """Whether some subscriber matches the ``objects`` key right now."""
        # The stub says bool; at runtime it is a MatchingStatus whose truth value is not defined.
        return bool(self._objects.matching_status.matching)  # type: ignore[attr-defined]

    def _end_track(self, tid: int) -> None:
        pub = self._tracks.pop(tid, None)
        if pub is not None:
            pub.delete()
            pub.undeclare()

    def status(self, payload: bytes) -> None:
        with self._lock:
            try:
                self._status.put(payload)
            except zenoh.ZError as exc:
                self.errors += 1
                log.warning("status publish failed: %s", exc)

    def close(self) -> None:
        """End every live track (DELETE), withdraw the token, close the session."""
        with self._lock:
            if self._session is None:
                return
            for tid in list(self._tracks):
                self._end_track(tid)
            self._alive.undeclare()
            for e in self._entities:
                e.undeclare()
            self._entities.clear()
            self._session.close()
            self._session = None

    def __enter__(self) -> Publisher:
        return self.open()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
