"""A typed client for programs that use a running stereod over Zenoh.

Messages arrive parsed (:class:`~stereod.bus.messages.ObjectsMessage` with its
:class:`~stereod.bus.messages.ObjectState` objects), together with the end of each track
(:class:`TrackEnded`, from the DELETE on the track's key) and the daemon's liveliness
(:class:`DaemonAlive`, from its ``alive`` token). Parsing is lenient: a newer daemon's extra
fields are ignored. A sample that does not parse is counted in ``Subscription.rejected`` and
skipped, never raised into Zenoh's thread. A callback::

    import zenoh
    from stereod.client import ObjectsMessage, TrackEnded, subscribe_objects, zenoh_config

    def on_event(event):
        if isinstance(event, ObjectsMessage):
            for o in event.objects:
                print(o.track_id, o.position_m, o.speed_mps, o.heading_deg)
        elif isinstance(event, TrackEnded):
            print("track", event.track_id, "ended")

    endpoint = "tcp/127.0.0.1:7447"  # where the daemon listens
    with zenoh.open(zenoh_config(endpoint)) as session, subscribe_objects(session, on_event):
        input("press Enter to stop\\n")

or an iterator, which also waits for the daemon before querying it::

    with zenoh.open(zenoh_config(endpoint)) as session:
        wait_alive(session, rig="minoru", timeout_s=10)
        print(query_stats(session, rig="minoru").pairs, "pairs so far")
        with object_events(session, rig="minoru") as events:
            for event in events:
                ...

Key expressions come from :mod:`stereod.bus.keys` (also available here as ``keys``).
"""

from __future__ import annotations

import json
import logging
import math
import os
import queue
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from types import TracebackType
from typing import TYPE_CHECKING, Any

import zenoh
from pydantic import ValidationError

from stereod.bus import keys
from stereod.bus.messages import (
    OBJECT_SCHEMA,
    OBJECTS_SCHEMA,
    STATS_SCHEMA,
    STATUS_SCHEMA,
    CanonicalGeometry,
    ImageInfo,
    ObjectsMessage,
    ObjectState,
    StatsMessage,
    StatusMessage,
)
from stereod.bus.publish import session_config
from stereod.daemon.config_zenoh import ZenohConfig
from stereod.errors import StereodError, describe_validation_error, one_line

if TYPE_CHECKING:
    from stereod.vision.calibration import Calibration

__all__ = [
    "DaemonAlive",
    "Event",
    "Image",
    "ImageInfo",
    "ObjectState",
    "ObjectsMessage",
    "QueryError",
    "StatsMessage",
    "StatusMessage",
    "Subscription",
    "TrackEnded",
    "keys",
    "object_events",
    "parse_payload",
    "query_calibration",
    "query_config",
    "query_stats",
    "subscribe_images",
    "subscribe_objects",
    "subscribe_status",
    "wait_alive",
    "zenoh_config",
]

log = logging.getLogger(__name__)


class QueryError(Exception):
    """A query got no usable reply (no daemon, a timeout, or an error reply)."""


@dataclass(frozen=True)
class TrackEnded:
    """A track of ``rig`` ended (its key got a DELETE): its id is never used again."""

    rig: str
    track_id: int


@dataclass(frozen=True)
class DaemonAlive:
    """The daemon of ``rig`` appeared (``alive``) or went away (not ``alive``)."""

    rig: str
    alive: bool


Event = ObjectsMessage | TrackEnded | DaemonAlive
"""What :func:`subscribe_objects` delivers."""


class Subscription:
    """Declared Zenoh entities of one subscription; undeclared on :meth:`close` or ``with``."""

    def __init__(self) -> None:
        self._entities: list[Any] = []
        self.rejected = 0
        """Samples that did not parse (logged once, then counted)."""

    def _rejected(self, key: str, exc: Exception) -> None:
        self.rejected += 1
        if self.rejected == 1:  # once, on one line (pydantic's own text spans several)
            why = describe_validation_error(exc) if isinstance(exc, ValidationError) else exc
            log.warning(
                "ignoring a sample on %s that does not parse: %s (further ones are not logged)",
                key,
                one_line(str(why))[:300],
            )

    def close(self) -> None:
        for e in self._entities:
            e.undeclare()
        self._entities.clear()

    def __enter__(self) -> Subscription:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def parse_payload(payload: bytes) -> ObjectsMessage | ObjectState | StatusMessage | Any:
    """Any stereod payload as its typed message when its ``schema`` names one this version
    knows (objects, object, status, stats); other JSON as plain data; None when not JSON (or
    nested too deep for Python's parser)."""
    try:
        data = json.loads(payload)
    except (ValueError, RecursionError):
        return None
    schema = data.get("schema") if isinstance(data, dict) else None
    if not isinstance(schema, str):
        return data
    family = schema.split("/", 1)[0]
    model = _MODELS.get(family)
    if model is None:
        return data
    try:
        return model.model_validate(data)
    except ValidationError:
        return data


_MODELS: dict[str, type[ObjectsMessage | ObjectState | StatusMessage | StatsMessage]] = {
    schema.split("/", 1)[0]: model
    for schema, model in (
        (OBJECTS_SCHEMA, ObjectsMessage),
        (OBJECT_SCHEMA, ObjectState),
        (STATUS_SCHEMA, StatusMessage),
        (STATS_SCHEMA, StatsMessage),
    )
}
"""Each message's class by its schema's family (the schema before its ``/version``), from the
schemas the daemon stamps."""


def subscribe_objects(
    session: zenoh.Session,
    callback: Callable[[Event], None],
    *,
    rig: str = keys.DEFAULT_RIG,
    prefix: str = keys.DEFAULT_PREFIX,
    track_ends: bool = True,
    liveliness: bool = True,
) -> Subscription:
    """Call ``callback`` (on a Zenoh thread) with every ``objects`` message of ``rig`` (``*``
    for every rig), each track's end, and the daemon's liveliness (the current state first)."""
    sub = Subscription()

    def on_objects(sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        try:
            msg = ObjectsMessage.model_validate_json(sample.payload.to_bytes())
        except (ValidationError, ValueError) as exc:
            sub._rejected(key, exc)
            return
        callback(msg)

    def on_track(sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.DELETE:
            return
        where = keys.parse(str(sample.key_expr), prefix=prefix)
        try:
            assert where is not None
            callback(TrackEnded(where[0], int(where[1].rsplit("/", 1)[-1])))
        except (AssertionError, ValueError) as exc:
            sub._rejected(str(sample.key_expr), exc)

    def on_alive(sample: zenoh.Sample) -> None:
        where = keys.parse(str(sample.key_expr), prefix=prefix)
        if where is not None:
            callback(DaemonAlive(where[0], sample.kind == zenoh.SampleKind.PUT))

    sub._entities.append(session.declare_subscriber(keys.objects(rig, prefix=prefix), on_objects))
    if track_ends:
        sub._entities.append(
            session.declare_subscriber(keys.track(rig, "*", prefix=prefix), on_track)
        )
    if liveliness:
        sub._entities.append(
            session.liveliness().declare_subscriber(
                keys.alive(rig, prefix=prefix), on_alive, history=True
            )
        )
    return sub


def subscribe_status(
    session: zenoh.Session,
    callback: Callable[[StatusMessage], None],
    *,
    rig: str = keys.DEFAULT_RIG,
    prefix: str = keys.DEFAULT_PREFIX,
) -> Subscription:
    """Call ``callback`` with every status message of ``rig`` (1 Hz and on change)."""
    sub = Subscription()

    def on_status(sample: zenoh.Sample) -> None:
        try:
            msg = StatusMessage.model_validate_json(sample.payload.to_bytes())
        except (ValidationError, ValueError) as exc:
            sub._rejected(str(sample.key_expr), exc)
            return
        callback(msg)

    sub._entities.append(session.declare_subscriber(keys.status(rig, prefix=prefix), on_status))
    return sub


@dataclass(frozen=True)
class Image:
    """One image from ``<prefix>/<rig>/image/<name>``: the JPEG bytes and what pair they show
    (``info.seq`` and ``info.t_ns`` are those of the pair's ``objects`` message)."""

    info: ImageInfo
    jpeg: bytes


def subscribe_images(
    session: zenoh.Session,
    callback: Callable[[Image], None],
    *,
    name: str = "overlay",
    rig: str = keys.DEFAULT_RIG,
    prefix: str = keys.DEFAULT_PREFIX,
) -> Subscription:
    """Call ``callback`` with every image ``name`` (``left``, ``right``, ``overlay``, ``mask``,
    or ``*``) of ``rig``. The daemon encodes an image only while someone subscribes to its key,
    at most ``daemon.image_rate_hz`` times a second."""
    sub = Subscription()

    def on_image(sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        try:
            if sample.attachment is None:
                raise ValueError("no attachment (an image carries its pair's seq and t_ns there)")
            info = ImageInfo.model_validate_json(sample.attachment.to_bytes())
        except (ValidationError, ValueError) as exc:
            sub._rejected(key, exc)
            return
        callback(Image(info, sample.payload.to_bytes()))

    sub._entities.append(session.declare_subscriber(keys.image(name, rig, prefix=prefix), on_image))
    return sub


class EventStream:
    """An iterator over :data:`Event` (see :func:`object_events`)."""

    def __init__(self, session: zenoh.Session, maxsize: int, **where: Any) -> None:
        self._queue: queue.Queue[Event] = queue.Queue(maxsize)
        self.dropped = 0
        """Events dropped because the consumer fell more than ``maxsize`` behind."""
        self._closed = threading.Event()
        self._sub = subscribe_objects(session, self._put, **where)

    def _put(self, event: Event) -> None:
        try:
            self._queue.put_nowait(event)
        except queue.Full:
            self.dropped += 1

    def get(self, timeout_s: float | None = None) -> Event | None:
        """The next event, or ``None`` after ``timeout_s`` seconds without one (``None`` or
        infinity: wait for one)."""
        try:
            return self._queue.get(timeout=_wait_s(timeout_s, forever=True))
        except queue.Empty:
            return None

    def __iter__(self) -> Iterator[Event]:
        while not self._closed.is_set():
            event = self.get(0.1)
            if event is not None:
                yield event

    def close(self) -> None:
        self._closed.set()
        self._sub.close()

    def __enter__(self) -> EventStream:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def object_events(
    session: zenoh.Session,
    *,
    rig: str = keys.DEFAULT_RIG,
    prefix: str = keys.DEFAULT_PREFIX,
    maxsize: int = 1000,
) -> EventStream:
    """The events of :func:`subscribe_objects` as an iterator (a context manager); at most
    ``maxsize`` wait, beyond that the newest are dropped and counted in ``dropped``."""
    return EventStream(session, maxsize, rig=rig, prefix=prefix)


def zenoh_config(
    *connect: str, listen: Sequence[str] = (), config_file: str | os.PathLike[str] | None = None
) -> zenoh.Config:
    """A Zenoh config for a program that uses a daemon: connect to each ``connect`` endpoint
    (where a daemon listens, e.g. ``"tcp/127.0.0.1:7447"``) and listen on ``listen`` only
    (nowhere by default: the program accepts no connection from anyone), with no multicast
    scouting. An endpoint that is not up yet (the program was started before the
    daemon) is tried again every 100 to 250 ms, not after Zenoh's default 1 to 4 s, so the
    program sees the daemon as soon as it listens. ``config_file``: a Zenoh JSON5 file to
    start from (TLS certificates and ``enable_mtls`` to reach a secured daemon), as a daemon's
    ``[zenoh] config_file``. A malformed endpoint, or a file that is bad or not there, is a
    ValueError naming it."""
    extra = {} if config_file is None else {"config_file": os.fspath(config_file)}
    try:
        cfg = ZenohConfig(connect=list(connect), listen=list(listen), **extra)
        return session_config(cfg, consumer=True)
    except ValidationError as exc:
        raise ValueError(describe_validation_error(exc, "zenoh")) from None
    except StereodError as exc:  # a bad file, or one that is not there
        raise ValueError(str(exc)) from None


def wait_alive(
    session: zenoh.Session,
    *,
    rig: str = keys.DEFAULT_RIG,
    prefix: str = keys.DEFAULT_PREFIX,
    timeout_s: float = 10.0,
) -> bool:
    """Wait until the daemon of ``rig`` is up (its liveliness token is declared last, so its
    queryables answer once it is seen); False after ``timeout_s`` seconds (infinity: wait
    for it)."""
    wait_s = _wait_s(timeout_s, forever=True)
    seen = threading.Event()
    sub = session.liveliness().declare_subscriber(
        keys.alive(rig, prefix=prefix),
        lambda s: seen.set() if s.kind == zenoh.SampleKind.PUT else None,
        history=True,
    )
    try:
        return seen.wait(wait_s)
    finally:
        sub.undeclare()


def _wait_s(timeout_s: float | None, *, forever: bool) -> float | None:
    """A timeout argument checked: where ``forever`` is allowed, seconds >= 0, or ``None`` or
    infinity for no limit (returned as ``None``); else a finite number of seconds > 0.
    Anything else is a ValueError."""
    if timeout_s is None and forever:
        return None
    if isinstance(timeout_s, bool) or not isinstance(timeout_s, (int, float)):
        raise ValueError(f"timeout_s must be a number of seconds, got {timeout_s!r}")
    if math.isinf(timeout_s) and timeout_s > 0 and forever:
        return None
    if not (math.isfinite(timeout_s) and (timeout_s >= 0 if forever else timeout_s > 0)):
        limit = "a number of seconds >= 0" if forever else "a finite number of seconds > 0"
        raise ValueError(f"timeout_s must be {limit}, got {timeout_s!r}")
    return float(timeout_s)


QUERY_RETRY_S = 0.1
"""How long (s) a query that nothing served waits before asking again, within its timeout: a
session just opened has not yet learnt of the daemons on the bus."""


def _query(session: zenoh.Session, key: str, timeout_s: float) -> bytes:
    """The first reply to a query of ``key`` within ``timeout_s``. Zenoh says at once when
    nothing on the bus serves a key as far as the session knows; a session opened a moment
    ago knows of no daemon yet, so the query is asked again until the timeout."""
    wait_s = _wait_s(timeout_s, forever=False)
    assert wait_s is not None
    end = time.monotonic() + wait_s
    while True:
        left = end - time.monotonic()
        asked = time.monotonic()
        for reply in session.get(key, timeout=max(left, 1e-3)):
            if reply.ok is not None:
                return reply.ok.payload.to_bytes()
            error = reply.err.payload.to_bytes()
            if error == b"Timeout":  # Zenoh's answer for a queryable that did not reply in time
                break
            raise QueryError(f"{key}: the daemon replied with an error: {error!r}")
        served = time.monotonic() - asked >= 0.5 * left  # (it waited for a reply: one serves it)
        if served or end - time.monotonic() <= QUERY_RETRY_S:
            break
        time.sleep(QUERY_RETRY_S)
    if not served:
        raise QueryError(
            f"{key}: no daemon on the bus answered it within {wait_s:g} s (is one running with "
            "this rig name and prefix, and reachable from this session's endpoints?)"
        )
    raise QueryError(f"{key}: no reply within {wait_s:g} s (is the daemon running? see wait_alive)")


def query_config(
    session: zenoh.Session,
    *,
    rig: str = keys.DEFAULT_RIG,
    prefix: str = keys.DEFAULT_PREFIX,
    timeout_s: float = 5.0,
) -> dict[str, Any]:
    """The daemon's effective configuration (the TOML's sections as a dict)."""
    data = json.loads(_query(session, keys.queryable("config", rig, prefix=prefix), timeout_s))
    if not isinstance(data, dict):
        raise QueryError("config: the reply is not a JSON object")
    return data


def query_calibration(
    session: zenoh.Session,
    *,
    rig: str = keys.DEFAULT_RIG,
    prefix: str = keys.DEFAULT_PREFIX,
    timeout_s: float = 5.0,
) -> Calibration | CanonicalGeometry:
    """The geometry in force: the calibration file's content, or the canonical rig's figures."""
    raw = _query(session, keys.queryable("calibration", rig, prefix=prefix), timeout_s)
    try:
        if json.loads(raw).get("geometry") == "canonical":
            return CanonicalGeometry.model_validate_json(raw)
        from stereod.vision.calibration import Calibration  # OpenCV: only for a calibration

        return Calibration.model_validate_json(raw)
    except (ValidationError, ValueError, AttributeError) as exc:
        raise QueryError(f"calibration: the reply does not parse: {exc}") from exc


def query_stats(
    session: zenoh.Session,
    *,
    rig: str = keys.DEFAULT_RIG,
    prefix: str = keys.DEFAULT_PREFIX,
    timeout_s: float = 5.0,
) -> StatsMessage:
    """Counters since the daemon started."""
    raw = _query(session, keys.queryable("stats", rig, prefix=prefix), timeout_s)
    try:
        return StatsMessage.model_validate_json(raw)
    except ValidationError as exc:
        raise QueryError(f"stats: the reply does not parse: {exc}") from exc
