"""``stereod view --foxglove``: one rig live in the Foxglove app, over the Foxglove WebSocket
protocol (the server is foxglove-sdk's), with the topics, ROS 2 types, frames and stamps of the
MCAP export (:mod:`stereod.ros.export_mcap`), so a layout made for the file works live too.

::

    daemon --Zenoh--> FoxgloveBridge: objects, track ends, liveliness, image/{left,right,
                      overlay} (only while a Foxglove client subscribes), calibration query
                        |  RosMessages (the export's mapping), CDR by the export's encoder
                        v
    Foxglove app <--ws://127.0.0.1:8766-- front <--loopback-- foxglove-sdk server (ros2msg
                                          schemas, cdr)

The front takes both names of the protocol, ``foxglove.sdk.v1`` (current Foxglove) and
``foxglove.websocket.v1`` (older releases, Lichtblick; the same messages, which foxglove-sdk
alone refuses with HTTP 400), and hands each connection on byte for byte, its header renamed.

Channels (``<rig>`` as in the export):

* ``/tf_static``: body frame, rig frame, both cameras; sent once the daemon's geometry is known
  (its ``calibration`` queryable) and again to every client that subscribes (the protocol has
  no latching);
* ``/stereod/<rig>/{left,right}/camera_info``: with every ``objects`` message, each eye at its
  own capture instant as in the export (:func:`eye_instants`, from the message's stamp and
  skew and the daemon's ``pairing.skew_compensation``), once the geometry is known;
* ``/stereod/<rig>/{left,right}/image/compressed`` and ``/stereod/<rig>/overlay/image/
  compressed`` (both eyes annotated side by side; not in the export): the daemon's JPEGs, an
  eye's stamped with its instant, the overlay with the pair's, subscribed on Zenoh only while
  a Foxglove client subscribes (the daemon encodes only for a listener), at most
  ``daemon.image_rate_hz`` a second;
* ``/stereod/<rig>/tracks/odom``, ``.../tracks/markers``, ``/stereod/<rig>/objects`` and one
  ``.../tracks/track_<id>/speed_heading`` per track (advertised at its first valid velocity,
  withdrawn once a message no longer holds it: as many channels as tracks alive at once; a
  Foxglove plot of an ended track keeps its points; advertised again, a few times, while no
  client subscribed to it, since a subscription can cross its advertisement). Markers live 3
  frame periods unless refreshed; a DELETEALL clears them when the daemon's liveliness token
  goes (it stopped or died).

A message is encoded only for a channel a client subscribes to; its log time is its stamp.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import socket
import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh

from stereod.bus import keys
from stereod.bus.messages import CanonicalGeometry
from stereod.client import (
    DaemonAlive,
    Event,
    Image,
    ObjectsMessage,
    QueryError,
    Subscription,
    TrackEnded,
    query_calibration,
    query_config,
    subscribe_images,
    subscribe_objects,
)
from stereod.errors import (
    NotInstalledError,
    StereodError,
    UnavailableError,
    UsageError,
    serve_hint,
)
from stereod.ros.mapping import RosMessage, RosMessages
from stereod.ros.names import cdr_encoder, ros2_msgdef
from stereod.sources.frames import Eye
from stereod.vision.calibration import Calibration, canonical

log = logging.getLogger(__name__)

DEFAULT_PORT = 8766
"""The WebSocket port (the web page of ``stereod view`` is on 8765)."""

_T_IMAGE = "sensor_msgs/msg/CompressedImage"
_T_INFO = "sensor_msgs/msg/CameraInfo"
_T_TF = "tf2_msgs/msg/TFMessage"
_T_ODOM = "nav_msgs/msg/Odometry"
_T_MARKERS = "visualization_msgs/msg/MarkerArray"
_T_VEC = "geometry_msgs/msg/Vector3Stamped"
_T_STRING = "std_msgs/msg/String"


SDK_PROTOCOL = "foxglove.sdk.v1"
"""The WebSocket subprotocol foxglove-sdk's server speaks (0.30)."""
OLD_PROTOCOL = "foxglove.websocket.v1"
"""The name older Foxglove releases, Lichtblick and roslibjs-era tools ask for: the same
messages under the protocol's earlier name, which foxglove-sdk refuses with HTTP 400."""

_HEAD_MAX = 65536
_SKEWS_KEPT = 256


def _read_head(conn: socket.socket) -> tuple[bytes, bytes]:
    """An HTTP head (up to the blank line) and whatever came after it."""
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = conn.recv(4096)
        if not chunk or len(data) > _HEAD_MAX:
            raise ConnectionError("no HTTP head")
        data += chunk
    head, _, rest = data.partition(b"\r\n\r\n")
    return head + b"\r\n\r\n", rest


def _with_protocol(head: bytes, protocol: str) -> bytes:
    """``head`` with its Sec-WebSocket-Protocol header set to ``protocol``."""
    lines = head.split(b"\r\n")
    for i, line in enumerate(lines):
        if line.lower().startswith(b"sec-websocket-protocol:"):
            lines[i] = b"Sec-WebSocket-Protocol: " + protocol.encode()
    return b"\r\n".join(lines)


def offers_only_old_protocol(head: bytes) -> bool:
    """Whether an upgrade request asks for ``foxglove.websocket.v1`` and not foxglove-sdk's."""
    offered: list[str] = []
    for line in head.split(b"\r\n"):
        name, _, value = line.partition(b":")
        if name.strip().lower() == b"sec-websocket-protocol":
            offered += [p.strip() for p in value.decode("latin-1").split(",")]
    return OLD_PROTOCOL in offered and SDK_PROTOCOL not in offered


def _pipe(src: socket.socket, dst: socket.socket) -> None:
    try:
        while chunk := src.recv(65536):
            dst.sendall(chunk)
    except OSError:
        pass
    with contextlib.suppress(OSError):
        dst.shutdown(socket.SHUT_WR)


class _ProtocolFront:
    """Listens on ``host:port`` for Foxglove clients and hands each connection to foxglove-sdk's
    server on a loopback port, byte for byte; a client offering only the protocol's older name
    is offered to the server as ``foxglove.sdk.v1`` and answered ``foxglove.websocket.v1``."""

    def __init__(self, host: str, port: int, backend_port: int) -> None:
        family, kind, proto, _, addr = socket.getaddrinfo(
            host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE
        )[0]
        self._sock = socket.socket(family, kind, proto)
        try:
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._sock.bind(addr)
            self._sock.listen(16)
        except OSError:
            self._sock.close()
            raise
        self.port = int(self._sock.getsockname()[1])
        self._backend = backend_port
        self._lock = threading.Lock()
        self._conns: set[socket.socket] = set()
        threading.Thread(target=self._accept, name="foxglove-front", daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                conn, _ = self._sock.accept()
            except OSError:  # closed
                return
            threading.Thread(
                target=self._serve, args=(conn,), name="foxglove-conn", daemon=True
            ).start()

    def _serve(self, client: socket.socket) -> None:
        backend: socket.socket | None = None
        try:
            client.settimeout(10.0)
            head, rest = _read_head(client)
            old = offers_only_old_protocol(head)
            if old:
                head = _with_protocol(head, SDK_PROTOCOL)
            backend = socket.create_connection(("127.0.0.1", self._backend), timeout=10.0)
            with self._lock:
                self._conns.update((client, backend))
            backend.sendall(head + rest)
            answer, more = _read_head(backend)
            if old and answer.startswith(b"HTTP/1.1 101"):
                answer = _with_protocol(answer, OLD_PROTOCOL)
            client.sendall(answer + more)
            client.settimeout(None)
            backend.settimeout(None)
            back = threading.Thread(target=_pipe, args=(backend, client), daemon=True)
            back.start()
            _pipe(client, backend)
            back.join()
        except (OSError, ConnectionError):
            log.debug("foxglove: a connection ended early", exc_info=True)
        finally:
            for conn in (client, backend):
                if conn is not None:
                    conn.close()
            with self._lock:
                self._conns.difference_update((client, backend))

    def close(self) -> None:
        """Stop listening and cut every connection."""
        self._sock.close()
        with self._lock:
            conns = list(self._conns)
        for conn in conns:
            with contextlib.suppress(OSError):
                conn.shutdown(socket.SHUT_RDWR)


def eye_instants(stamp_ns: int, skew_ns: int, compensated: bool) -> tuple[int, int]:
    """The left and right capture instants (ns) of a pair stamped ``stamp_ns`` with ``skew_ns``
    (right minus left): the pipeline's instant is the earlier eye's when it brings both eyes to
    one instant (``pairing.skew_compensation``), else the midpoint ``(left + right) // 2``."""
    if compensated:
        left = stamp_ns if skew_ns >= 0 else stamp_ns - skew_ns
    else:
        left = stamp_ns - skew_ns // 2
    return left, left + skew_ns


def calibration_of(reply: Calibration | CanonicalGeometry) -> Calibration:
    """The daemon's geometry (its ``calibration`` queryable's reply) as a calibration."""
    if isinstance(reply, CanonicalGeometry):
        return canonical(reply.baseline_m, reply.hfov_deg, reply.width_px, reply.height_px)
    return reply


def _listener(bridge: FoxgloveBridge) -> Any:
    """foxglove-sdk's server listener, handing subscriptions to ``bridge``."""
    from foxglove.websocket import ChannelView, Client, ServerListener

    class Listener(ServerListener):
        def on_subscribe(self, client: Client, channel: ChannelView) -> None:
            bridge.on_subscribe(client, channel)

        def on_unsubscribe(self, client: Client, channel: ChannelView) -> None:
            bridge.on_unsubscribe(client, channel)

    return Listener()


READVERTISE_AFTER = 5
"""Messages a speed_heading channel may go unheard before it is advertised again."""
READVERTISE_TRIES = 3
"""How many times such a channel is advertised again (after 5, 10 and 20 messages more)."""


class FoxgloveBridge:
    """Serves what one rig publishes on ``session`` to Foxglove on ``ws://host:port`` (port 0:
    any free one). :meth:`start` returns once the server listens; :meth:`stop` (or the end of
    ``with``) closes it and every Zenoh subscription it made. The session stays the caller's.
    ``serves``: what its keys are of, for its log line."""

    serves = "rig"

    def __init__(
        self,
        session: zenoh.Session,
        *,
        rig: str = keys.DEFAULT_RIG,
        prefix: str = keys.DEFAULT_PREFIX,
        host: str = "127.0.0.1",
        port: int = DEFAULT_PORT,
    ) -> None:
        self.session = session
        self.rig = rig
        self.prefix = prefix
        self.host = host
        self.port = port
        self.ros = RosMessages(rig)
        self.names = self.ros.names
        self.logged: dict[str, int] = {}
        """Messages sent to clients so far, by topic."""
        self._lock = threading.Lock()
        self._ctx: Any = None
        self._server: Any = None
        self._front: _ProtocolFront | None = None
        self._channels: dict[str, tuple[Any, Callable[[dict[str, Any]], bytes]]] = {}
        # speed_heading topic -> (messages with no sink since advertised, advertised again)
        self._unheard: dict[str, tuple[int, int]] = {}
        self._heard: set[str] = set()  # speed_heading topics that have had a subscriber
        self._watching = 0  # clients' subscriptions now, on every channel
        self._images = {
            self.names.image_topic(Eye.LEFT): ("left", self.names.eye_frame(Eye.LEFT)),
            self.names.image_topic(Eye.RIGHT): ("right", self.names.eye_frame(Eye.RIGHT)),
            self.names.overlay_topic: ("overlay", self.names.optical_frame),
        }
        self._image_subs: dict[str, tuple[int, Subscription]] = {}
        self._subs: list[Subscription] = []
        self._alive: bool | None = None
        self._compensated = True  # the daemon's pairing.skew_compensation, default until asked
        self._skews: dict[int, int] = {}  # pair seq -> skew_ns, the last _SKEWS_KEPT pairs

    @property
    def url(self) -> str:
        """``ws://host:port``, the address to give Foxglove's "Open connection"."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"

    # -- life ----------------------------------------------------------------------------------

    def start(self) -> FoxgloveBridge:
        """Start the server and subscribe to the rig; :class:`UnavailableError` when the port
        is in use, :class:`UsageError` (the flags' host or port) when the address cannot be
        bound otherwise, :class:`NotInstalledError` without foxglove-sdk."""
        try:
            import foxglove
        except ImportError as exc:
            raise NotInstalledError(
                "stereod view --foxglove needs foxglove-sdk: pip install 'stereod[foxglove]'"
            ) from exc
        self._ctx = foxglove.Context()
        names = self.names
        fixed = [
            (names.tf_static_topic, _T_TF),
            *((names.camera_info_topic(eye), _T_INFO) for eye in Eye),
            *((topic, _T_IMAGE) for topic in self._images),
            (names.odom_topic, _T_ODOM),
            (names.markers_topic, _T_MARKERS),
            (names.objects_topic, _T_STRING),
        ]
        for topic, typename in fixed:
            self._channel(topic, typename)
        try:
            self._server = foxglove.start_server(
                name=f"stereod {self.rig}",
                host="127.0.0.1",
                port=0,
                context=self._ctx,
                server_listener=_listener(self),
            )
            self._front = _ProtocolFront(self.host, self.port, int(self._server.port))
        except (RuntimeError, OSError) as exc:
            if self._server is not None:
                self._server.stop()
                self._server = None
            self._close_channels()
            reason = (exc.strerror or str(exc)) if isinstance(exc, OSError) else str(exc)
            reason = reason.removeprefix("FoxgloveError: ")
            in_use = isinstance(exc, OSError) and exc.errno == errno.EADDRINUSE
            hint = serve_hint(exc, "--foxglove-host", "--foxglove-port")
            text = f"foxglove: cannot serve on {self.host}:{self.port}: {reason} ({hint})"
            if in_use or "Address already in use" in reason:  # taken now, maybe free later
                raise UnavailableError(text) from exc
            raise UsageError(text) from exc  # a host or port of the flags that cannot be
        self.port = self._front.port
        self._subs.append(
            subscribe_objects(self.session, self._on_event, rig=self.rig, prefix=self.prefix)
        )
        log.info("foxglove: serving %s %s at %s", self.serves, self.rig, self.url)
        return self

    def stop(self) -> None:
        """Close the Zenoh subscriptions and the server (idempotent)."""
        with self._lock:
            subs = self._subs + [s for _, s in self._image_subs.values()]
            self._subs, self._image_subs = [], {}
            # nothing is sent, and no channel made, from now on; the context itself goes last,
            # outside the lock: dropping it closes what still uses it, and foxglove-sdk then
            # calls the listener (on_unsubscribe, which takes the lock) in this thread
            ctx, self._ctx = self._ctx, None
        for s in subs:
            s.close()
        if self._front is not None:
            self._front.close()
            self._front = None
        if self._server is not None:
            self._server.stop()
            self._server = None
        self._close_channels()
        with self._lock:
            self._watching = 0
        del ctx

    def __enter__(self) -> FoxgloveBridge:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- foxglove-sdk's ServerListener (its threads) -------------------------------------------

    def on_subscribe(self, client: Any, channel: Any) -> None:
        """A client subscribed: send it ``/tf_static``; start an image's Zenoh subscription."""
        try:
            topic = str(channel.topic)
            with self._lock:
                self._watching += 1
            if topic == self.names.tf_static_topic:
                self._send_tf()
            elif topic in self._images:
                self._image_wanted(topic, +1)
        except Exception:  # never into foxglove-sdk's thread
            log.exception("foxglove: handling a subscription to %s failed", channel.topic)

    def on_unsubscribe(self, client: Any, channel: Any) -> None:
        """A client unsubscribed (or left): stop an image's Zenoh subscription when unwatched."""
        try:
            with self._lock:
                self._watching -= 1
            if str(channel.topic) in self._images:
                self._image_wanted(str(channel.topic), -1)
        except Exception:
            log.exception("foxglove: handling an unsubscription from %s failed", channel.topic)

    def _image_wanted(self, topic: str, delta: int) -> None:
        name, frame_id = self._images[topic]
        with self._lock:
            count, sub = self._image_subs.pop(topic, (0, None))
            count = max(0, count + delta)
            if count > 0 and sub is None and self._server is not None:
                sub = subscribe_images(
                    self.session,
                    lambda image: self._on_image(topic, frame_id, image),
                    name=name,
                    rig=self.rig,
                    prefix=self.prefix,
                )
                log.info("foxglove: image %s subscribed", name)
            if count > 0 and sub is not None:
                self._image_subs[topic] = (count, sub)
                sub = None
        if sub is not None:
            sub.close()
            log.info("foxglove: image %s unsubscribed", name)

    # -- Zenoh side (Zenoh's threads) ----------------------------------------------------------

    def _on_event(self, event: Event) -> None:
        try:
            if isinstance(event, ObjectsMessage):
                self._on_objects(event)
            elif isinstance(event, TrackEnded):
                with self._lock:
                    topic = self.names.speed_heading_topic(event.track_id)
                    entry = self._channels.pop(topic, None)
                    self._forget_unheard([topic])
                if entry is not None:
                    entry[0].close()
            elif isinstance(event, DaemonAlive):
                self._on_alive(event.alive)
        except Exception:  # one bad message must not end the subscription
            log.exception("foxglove: handling %s failed", type(event).__name__)

    def _on_objects(self, msg: ObjectsMessage) -> None:
        alive = {self.names.speed_heading_topic(o.track_id) for o in msg.objects}
        with self._lock:
            gone = [t for t in self._channels if t.endswith("/speed_heading") and t not in alive]
            closing = [self._channels.pop(t)[0] for t in gone]
            self._forget_unheard([t for t in {*self._unheard, *self._heard} if t not in alive])
        for ch in closing:
            ch.close()
        with self._lock:
            messages = self.ros.objects(msg)
            self._skews[msg.seq] = msg.skew_ns
            while len(self._skews) > _SKEWS_KEPT:
                del self._skews[next(iter(self._skews))]
            stamps = eye_instants(msg.stamp_utc_ns, msg.skew_ns, self._compensated)
            for eye, stamp in zip(Eye, stamps, strict=True):
                info = self.ros.camera_info(eye, stamp)
                if info is not None:
                    messages.append(info)
        for m in messages:
            self._send(m)

    def _on_alive(self, alive: bool) -> None:
        if not alive and self._alive is not False:  # its markers must not outlive it
            with self._lock:
                clear = self.ros.delete_all_markers(time.time_ns())
            self._send(clear)
        if alive and self._alive is False:  # a new daemon: its track ids start again
            with self._lock:
                self.ros.forget_tracks()
                stale = [t for t in self._channels if t.endswith("/speed_heading")]
                closing = [self._channels.pop(t)[0] for t in stale]
                self._unheard.clear()
                self._heard.clear()
            for ch in closing:
                ch.close()
        self._alive = alive
        if alive:
            threading.Thread(target=self._ask_geometry, name="foxglove-query", daemon=True).start()

    def _ask_geometry(self) -> None:
        """Ask the daemon for its geometry (off Zenoh's callback thread), then send tf."""
        try:
            reply = query_calibration(self.session, rig=self.rig, prefix=self.prefix)
            cal = calibration_of(reply)
            config = query_config(self.session, rig=self.rig, prefix=self.prefix)
            pairing = config.get("pairing")
            if isinstance(pairing, dict) and isinstance(pairing.get("skew_compensation"), bool):
                self._compensated = pairing["skew_compensation"]
            with self._lock:
                self.ros.set_geometry(cal)
        except (QueryError, zenoh.ZError, StereodError) as exc:
            log.warning("foxglove: no geometry from the daemon (%s): no tf or camera_info", exc)
            return
        self._send_tf()

    def _on_image(self, topic: str, frame_id: str, image: Image) -> None:
        try:
            stamp = image.info.stamp_utc_ns
            if image.info.name in ("left", "right"):  # each eye at its own capture instant
                with self._lock:
                    skew = self._skews.get(image.info.seq)
                if skew is not None:
                    left, right = eye_instants(stamp, skew, self._compensated)
                    stamp = left if image.info.name == "left" else right
            self._send(self.ros.compressed_image(topic, frame_id, "jpeg", image.jpeg, stamp))
        except Exception:
            log.exception("foxglove: sending image %s failed", image.info.name)

    # -- channels ------------------------------------------------------------------------------

    def _send_tf(self) -> None:
        with self._lock:
            tf = self.ros.tf_static(time.time_ns())
        if tf is not None:
            self._send(tf)

    def _channel(
        self, topic: str, typename: str
    ) -> tuple[Any, Callable[[dict[str, Any]], bytes]] | None:
        with self._lock:
            entry = self._channels.get(topic)
            if entry is None:
                if self._ctx is None:
                    return None
                from foxglove import Channel, Schema

                schema = Schema(
                    name=typename, encoding="ros2msg", data=ros2_msgdef(typename).encode()
                )
                channel = Channel(topic, schema=schema, message_encoding="cdr", context=self._ctx)
                entry = self._channels[topic] = (channel, cdr_encoder(typename))
            return entry

    def _send(self, m: RosMessage) -> None:
        entry = self._channel(m.topic, m.typename)
        if entry is None:
            return
        channel, encode = entry
        if not channel.has_sinks():
            if m.topic.endswith("/speed_heading"):
                self._unheard_once(m.topic, channel)
            return
        if m.topic not in self._heard and m.topic.endswith("/speed_heading"):
            with self._lock:
                self._heard.add(m.topic)
        channel.log(encode(m.body), log_time=m.stamp_ns)
        with self._lock:
            self.logged[m.topic] = self.logged.get(m.topic, 0) + 1

    def _unheard_once(self, topic: str, channel: Any) -> None:
        """A speed_heading channel no client has subscribed to, while clients watch others, is
        advertised again (closed; the next message makes it anew) after :data:`READVERTISE_AFTER`
        messages, up to :data:`READVERTISE_TRIES` times at doubling gaps: foxglove-sdk advertises
        a channel before it registers it, and a subscription in between is refused for good."""
        with self._lock:
            entry = self._channels.get(topic)
            if entry is None or entry[0] is not channel or topic in self._heard:
                return  # closed meanwhile, or once subscribed: nothing to count
            n, tries = self._unheard.get(topic, (0, 0))
            n += 1
            again = (
                tries < READVERTISE_TRIES and n >= READVERTISE_AFTER << tries and self._watching > 0
            )
            if again:
                self._unheard[topic] = (0, tries + 1)
                del self._channels[topic]
            else:
                self._unheard[topic] = (n, tries)
        if again:
            channel.close()

    def _forget_unheard(self, topics: list[str]) -> None:
        """Drop what :meth:`_unheard_once` kept of channels closed for good (under the lock)."""
        for t in topics:
            self._unheard.pop(t, None)
            self._heard.discard(t)

    def _close_channels(self) -> None:
        with self._lock:
            channels = [ch for ch, _ in self._channels.values()]
            self._channels.clear()
            self._unheard.clear()
            self._heard.clear()
        for ch in channels:
            ch.close()
