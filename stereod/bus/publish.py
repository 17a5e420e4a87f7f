"""Everything stereod says on Zenoh (design sec. 4), behind one small class.

Keys under ``<prefix>/<rig>``: ``objects`` (one message per pair, congestion DROP, DATA_HIGH),
``objects/<track_id>`` (one publisher per live track, a DELETE when it ends), ``status``
(re-sent as soon as a subscriber appears), the ``config``, ``calibration`` and ``stats``
queryables, and the ``alive`` liveliness token, declared last so that a client that sees it can
query everything else. Publishing never blocks the pipeline: puts use congestion DROP.
"""

from __future__ import annotations

import collections
import contextlib
import json
import logging
import re
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from types import TracebackType
from typing import Any

import zenoh

from stereod.bus import keys
from stereod.bus.endpoints import check_endpoint
from stereod.bus.messages import OBJECT_SCHEMA, OBJECTS_SCHEMA, STATUS_SCHEMA, encoding_for
from stereod.daemon.config_zenoh import ZenohConfig
from stereod.errors import ConfigError, MissingInputError, UnavailableError
from stereod.files.nesting import Syntax, check_depth
from stereod.files.paths import read_input_file, shown, text_path

log = logging.getLogger(__name__)


def zenoh_reason(exc: BaseException, limit: int = 160) -> str:
    """The first meaningful sentence of a Zenoh error: without the build paths of the Rust
    sources (``at /root/.cargo/...rs:62.``), the serde wrapping and the parser's ASCII art."""
    text = str(exc)
    inner = re.search(r'msg: "((?:[^"\\]|\\.)*)"', text)
    if inner:
        text = inner.group(1).replace('\\"', '"')
    text = re.sub(r"\s+at /\S+\.rs:\d+\.?", "", text)
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    where = next((ln[4:] for ln in lines if ln.startswith("--> ")), None)
    note = next((ln[2:] for ln in lines if ln.startswith("= ")), None)
    if note is not None:
        text = f"{note} (line:column {where})" if where else note
    text = " ".join(text.split()).rstrip(".")
    if len(text) > limit:
        text = text[: limit - 3] + "..."
    return text or type(exc).__name__


CONNECT_RETRY = {"period_init_ms": 100, "period_max_ms": 250, "period_increase_factor": 2}
"""How often an endpoint in ``connect`` that does not answer is tried again (Zenoh's default
starts at 1 s and grows to 4 s, so a subscriber started before the daemon missed its first
seconds; a refused TCP connection costs next to nothing)."""


def check_zenoh_file(path: Path) -> None:
    """Refuse a Zenoh config file before Zenoh parses it: missing or unreadable (66, as any
    input a configuration names), not a regular file (66), too large, or nested too deep for
    Zenoh's parser (whose stack overflows on it: the process would die by SIGSEGV) (78)."""
    try:
        data = read_input_file(path, "a Zenoh config file", too_large=ConfigError)
    except OSError as exc:
        reason = "no such file" if isinstance(exc, FileNotFoundError) else exc.strerror
        raise MissingInputError(
            f"{shown(path)}: cannot read the Zenoh config file: {reason} (zenoh.config_file)"
        ) from exc
    syntax: Syntax = "yaml" if path.suffix in (".yaml", ".yml") else "json5"
    check_depth(
        data.decode("utf-8", "replace"), syntax, f"{shown(path)} (zenoh.config_file)", ConfigError
    )


DEFAULT_LISTEN: dict[str, list[str]] = {
    "peer": ["tcp/127.0.0.1:0"],
    "router": ["tcp/127.0.0.1:7447"],
    "client": [],
}
"""Where a daemon's session listens when nobody said where: loopback only (Zenoh's own default
is every interface, ``tcp/[::]:0`` for a peer), so a daemon started without ``listen`` is
reachable from this machine alone. A consumer (``subscribe``, ``view``, the client helpers)
listens nowhere unless told to."""


def _zenoh_default(key: str) -> str:
    """Zenoh's built-in value of ``key`` (JSON), to tell whether a config file changed it."""
    return str(zenoh.Config().get_json(key))


def _check_file_endpoints(zc: zenoh.Config, path: Path) -> None:
    """Refuse a malformed endpoint in a Zenoh file's ``connect`` or ``listen`` as the same
    endpoint is refused in stereod's own settings (Zenoh takes ``tcp/host:notaport`` and then
    never connects, or fails to open naming neither the file nor the endpoint)."""
    for section in ("connect", "listen"):
        given = json.loads(zc.get_json(f"{section}/endpoints"))
        lists = given.values() if isinstance(given, dict) else [given]  # per mode, or one list
        for endpoint in (e for listed in lists for e in (listed or [])):
            try:
                check_endpoint(str(endpoint))
            except ValueError as exc:
                raise ConfigError(
                    f"{shown(path)}: {section}.endpoints {endpoint!r}: {exc} (zenoh.config_file)"
                ) from None


def session_config(cfg: ZenohConfig, *, consumer: bool = False) -> zenoh.Config:
    """A Zenoh config from ours. Without ``config_file``: mode, endpoints, and no multicast
    scouting unless asked. With it, the file (Zenoh's own JSON5: TLS, access control, ...) is
    the base and only the settings given in stereod's config, environment or flags go on top.

    Nothing listens where the user did not say: without ``listen`` (and without a config file
    that changes Zenoh's default listeners) a daemon listens on loopback only
    (:data:`DEFAULT_LISTEN`) and a ``consumer`` (a program that connects to a daemon) on no
    endpoint at all; multicast scouting, which binds a UDP socket on every interface, stays off
    unless ``multicast_scouting`` (or the file) turns it on."""
    given = cfg.model_fields_set if cfg.config_file is not None else set(ZenohConfig.model_fields)
    if cfg.config_file is not None:
        name = text_path(cfg.config_file, "Zenoh config", ConfigError)
        check_zenoh_file(cfg.config_file)
        try:
            zc = zenoh.Config.from_file(name)
        except zenoh.ZError as exc:
            raise ConfigError(
                f"{cfg.config_file}: invalid Zenoh config file: {zenoh_reason(exc)} "
                "(zenoh.config_file)"
            ) from exc
        _check_file_endpoints(zc, cfg.config_file)
    else:
        zc = zenoh.Config()
    settings: list[tuple[str, str, object]] = []
    if "mode" in given:
        settings.append(("mode", "mode", cfg.mode))
    if "multicast_scouting" in given:
        settings.append(
            ("multicast_scouting", "scouting/multicast/enabled", cfg.multicast_scouting)
        )
    elif zc.get_json("scouting/multicast/enabled") == _zenoh_default("scouting/multicast/enabled"):
        settings.append(("multicast_scouting", "scouting/multicast/enabled", False))
    if cfg.config_file is None:
        settings.append(("multicast_scouting", "scouting/delay", 0))
    if cfg.connect:
        settings.append(("connect", "connect/endpoints", cfg.connect))
        if cfg.config_file is None:  # a peer not up yet is tried again soon, not after 1-4 s
            settings.append(("connect", "connect/retry", CONNECT_RETRY))
    if cfg.listen:
        settings.append(("listen", "listen/endpoints", cfg.listen))
    elif zc.get_json("listen/endpoints") == _zenoh_default("listen/endpoints"):
        mode = cfg.mode if "mode" in given else json.loads(zc.get_json("mode")) or "peer"
        listen = [] if consumer else DEFAULT_LISTEN.get(mode, [])
        settings.append(("listen", "listen/endpoints", listen))
    for field, key, value in settings:
        try:
            zc.insert_json5(key, json.dumps(value))
        except zenoh.ZError as exc:
            raise ConfigError(
                f"zenoh.{field} = {json.dumps(value)[:80]}: {zenoh_reason(exc)}"
            ) from exc
    if consumer and cfg.config_file is not None and not _reaches_out(zc):
        raise ConfigError(
            f"{cfg.config_file}: the Zenoh session would have no endpoint to connect to or "
            "listen on, and multicast scouting is off, so it would reach no daemon: add "
            'connect: {endpoints: ["tcp/HOST:7447"]} to the file, or give --connect'
        )
    return zc


def _mode(zc: zenoh.Config) -> str:
    return json.loads(zc.get_json("mode")) or "peer"  # Zenoh's default


def _endpoints(zc: zenoh.Config, key: str) -> list[str]:
    """The endpoints at ``key`` (``connect/endpoints``, ``listen/endpoints``) for the
    config's mode (a file may give them per mode)."""
    given = json.loads(zc.get_json(key)) or []
    return list(given.get(_mode(zc), []) if isinstance(given, dict) else given)


def _reaches_out(zc: zenoh.Config) -> bool:
    """Whether a session of ``zc`` can meet another: an endpoint, or multicast scouting."""
    scouting = json.loads(zc.get_json("scouting/multicast/enabled"))
    return bool(_endpoints(zc, "connect/endpoints") or _endpoints(zc, "listen/endpoints")) or (
        scouting is True
    )


def open_session(cfg: ZenohConfig, *, consumer: bool = False) -> zenoh.Session:
    """Open a session (a ``consumer`` listens nowhere unless ``cfg.listen`` says where, see
    :func:`session_config`); a bad endpoint becomes a :class:`ConfigError` naming it, a router
    that cannot be reached (client mode) an :class:`UnavailableError`."""
    zc = session_config(cfg, consumer=consumer)
    try:
        return zenoh.open(zc)
    except zenoh.ZError as exc:
        ends = ", ".join(
            f"{k}={v}" for k, v in (("listen", cfg.listen), ("connect", cfg.connect)) if v
        )
        reason = zenoh_reason(exc)
        text = f"zenoh: cannot open a session{f' ({ends})' if ends else ''}: {reason}"
        if "Unable to connect" in reason:  # a router that is down now may be up later
            raise UnavailableError(f"{text}; is the router running?") from exc
        if "Address already in use" in reason:  # taken now, maybe free later (a restart)
            raise UnavailableError(
                f"{text}; another process listens there (a daemon still stopping, or another "
                "one: give each its own endpoint)"
            ) from exc
        raise ConfigError(text) from exc


def close_session(session: zenoh.Session) -> None:
    """Close a session. A peer that stopped answering (a frozen subscriber) makes Zenoh's close
    time out after about ten seconds; the session is gone for this process all the same, so
    that is logged, not raised: a program that ends cleanly does not fail on its way out."""
    try:
        session.close()
    except zenoh.ZError as exc:
        log.warning("zenoh: closing the session: %s (a peer stopped answering)", zenoh_reason(exc))


@contextlib.contextmanager
def opened_session(cfg: ZenohConfig, *, consumer: bool = False) -> Iterator[zenoh.Session]:
    """:func:`open_session` for a ``with`` block, closed by :func:`close_session` after it."""
    session = open_session(cfg, consumer=consumer)
    try:
        yield session
    finally:
        close_session(session)


TOKEN_SETTLE_S = 0.2
"""How long (s) a session just connected to peers waits before asking again whether another
daemon's ``alive`` token is on the bus (the peers' tokens reach it a moment after the
connection)."""


def reachable(session: zenoh.Session, timeout_s: float = 1.0) -> bool:
    """Whether the session has a Zenoh peer or router to talk to, waiting up to ``timeout_s``
    seconds for one to answer (connecting takes milliseconds on a LAN)."""
    deadline = time.monotonic() + timeout_s
    while True:
        if any(True for _ in session.info.peers_zid()) or any(
            True for _ in session.info.routers_zid()
        ):
            return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.02)


class Publisher:
    """The daemon's Zenoh face; use as a context manager around the daemon's life."""

    def __init__(
        self,
        cfg: ZenohConfig,
        rig: str,
        queryables: dict[str, Callable[[], bytes]],
        on_status_subscriber: Callable[[], None] | None = None,
        session: zenoh.Session | None = None,
    ) -> None:
        self.rig = rig
        self.prefix = cfg.prefix
        self.base = keys.base(rig, prefix=cfg.prefix)
        self._cfg = cfg
        self._queryables = queryables
        self._on_status_subscriber = on_status_subscriber
        self._session: zenoh.Session | None = None
        self._given = session
        """A session opened by the caller, who keeps it open (and closes it) after this."""
        self._tracks: dict[int, zenoh.Publisher] = {}
        self._entities: list[Any] = []
        self._lock = threading.Lock()
        self.published = 0
        self.errors = 0
        self.rig_taken = False
        self._sent: collections.deque[int] = collections.deque(maxlen=16)
        self.foreign_status_at: float | None = None
        """When (monotonic s) a status this publisher did not send last came on its own status
        key: another daemon publishes the same rig (Zenoh merges two liveliness tokens on one
        key, so the first of two daemons learns of the second only this way)."""
        """Whether another daemon's ``alive`` token for this rig was on the bus at open: two
        daemons under one rig name mix their messages and answer each other's queries."""

    def open(self) -> Publisher:
        s = self._given if self._given is not None else open_session(self._cfg)
        self._session = s
        try:
            self._declare(s)
        except BaseException:  # nothing declared stays behind, and a session of ours closes
            self.close()
            raise
        return self

    def _declare(self, s: zenoh.Session) -> None:
        """Declare the publishers, probes, subscriber, queryables and token on ``s``."""
        if self._cfg.connect and not reachable(s):
            log.warning(
                "no Zenoh peer or router reachable at %s; publishing anyway, and connecting "
                "when one answers",
                ", ".join(self._cfg.connect),
            )
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
        # Never put: there only for its matching status, which a subscriber to the tracks'
        # keys (``objects/*``) sets and one to the ``objects`` key alone does not.
        self._track_probe = s.declare_publisher(keys.track(self.rig, 0, prefix=self.prefix))
        self._entities.append(self._track_probe)
        if self._on_status_subscriber is not None:
            # A probe for the matching status alone, reaching remote sessions only: this
            # session's own subscriber to the key (for another daemon's status, below) would
            # keep the status key matched for ever, and no new subscriber would be told.
            probe = s.declare_publisher(
                keys.status(self.rig, prefix=self.prefix),
                allowed_destination=zenoh.Locality.REMOTE,
            )
            # The listener goes before its publisher (undeclared in this order).
            self._entities += [probe.declare_matching_listener(self._matching), probe]
        self._entities.append(
            s.declare_subscriber(keys.status(self.rig, prefix=self.prefix), self._on_status)
        )
        for name, fn in self._queryables.items():
            self._entities.append(
                s.declare_queryable(
                    keys.queryable(name, self.rig, prefix=self.prefix), self._replier(name, fn)
                )
            )
        alive = keys.alive(self.rig, prefix=self.prefix)
        self.rig_taken = self._token_on_bus(s, alive)
        self._alive = s.liveliness().declare_token(alive)
        log.info("zenoh session open, publishing under %s/", self.base)

    def _token_on_bus(self, s: zenoh.Session, alive: str) -> bool:
        """Whether a liveliness token on ``alive`` is on the bus now. A peer just connected
        may not have told this session of its tokens yet (a query then finds none at once), so
        with peers to ask, an empty answer is asked again after ``TOKEN_SETTLE_S``."""
        for attempt in range(2):
            if any(r.ok is not None for r in s.liveliness().get(alive, timeout=1.0)):
                return True
            if attempt or not any(True for _ in s.info.peers_zid()):
                return False
            time.sleep(TOKEN_SETTLE_S)
        return False

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
                self.published += 1
            except zenoh.ZError as exc:
                self.errors += 1
                log.warning("publish failed: %s", exc)
            for tid in ended:  # each, whatever became of the others
                self._end_track(tid)

    def objects_end(self, ended: list[int]) -> None:
        """A DELETE on each ended track's key, with no objects message (end of input)."""
        with self._lock:
            for tid in ended:
                self._end_track(tid)

    def has_objects_subscriber(self) -> bool:
        """Whether some subscriber matches the ``objects`` key or the tracks' keys right now."""
        # The stub says bool; at runtime it is a MatchingStatus whose truth value is not defined.
        return any(
            bool(p.matching_status.matching)  # type: ignore[attr-defined]
            for p in (self._objects, self._track_probe)
        )

    def _end_track(self, tid: int) -> None:
        """A DELETE on the track's key, and its publisher withdrawn (even when the DELETE
        fails: counted in :attr:`errors`, never raised)."""
        pub = self._tracks.pop(tid, None)
        if pub is None:
            return
        try:
            pub.delete()
        except zenoh.ZError as exc:
            self.errors += 1
            log.warning("publish failed: the DELETE of track %d: %s", tid, exc)
        with contextlib.suppress(zenoh.ZError):
            pub.undeclare()

    def _on_status(self, sample: zenoh.Sample) -> None:
        if hash(sample.payload.to_bytes()) not in self._sent:
            self.foreign_status_at = time.monotonic()

    def status(self, payload: bytes) -> None:
        with self._lock:
            self._sent.append(hash(payload))  # before the put: its echo may come at once
            try:
                self._status.put(payload)
            except zenoh.ZError as exc:
                self.errors += 1
                log.warning("status publish failed: %s", exc)

    def close(self) -> None:
        """End every live track (DELETE), withdraw the token, close the session (one the
        caller gave stays open, with nothing of this publisher left on it)."""
        with self._lock:
            if self._session is None:
                return
            for tid in list(self._tracks):
                self._end_track(tid)
            declared = (getattr(self, n, None) for n in ("_alive", "_objects", "_status"))
            alive, objects, status = declared  # any may be missing: an open that failed
            for e in (alive, *self._entities, objects, status):
                if e is not None:
                    with contextlib.suppress(zenoh.ZError):
                        e.undeclare()
            self._entities.clear()
            if self._given is None:
                close_session(self._session)
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


def session_summary(cfg: ZenohConfig, *, consumer: bool = False) -> str:
    """The mode and endpoints a session opened with ``cfg`` takes, a config file's included,
    for a start-up line: ``client, to tcp/10.0.0.5:7447``."""
    zc = session_config(cfg, consumer=consumer)
    said = [f"to {', '.join(e)}" for e in [_endpoints(zc, "connect/endpoints")] if e]
    said += [f"listening on {', '.join(e)}" for e in [_endpoints(zc, "listen/endpoints")] if e]
    if not said:
        said = ["with no endpoint to connect to or listen on"]
    return f"{_mode(zc)}, {'; '.join(said)}"
