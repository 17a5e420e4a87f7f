"""ROS 2 live: the daemon as a ROS 2 node on the Zenoh bus, the way rmw_zenoh speaks (no bridge).

With ``[ros2] enabled = true`` a daemon (``stereod run``, ``stereod replay``) also publishes the
MCAP export's messages (:mod:`stereod.ros.export_mcap`, same topics, types, frames and stamps) the
way ``rmw_zenoh_cpp`` of ROS 2 **Jazzy** and **Kilted** does, so a ROS 2 machine with
``RMW_IMPLEMENTATION=rmw_zenoh_cpp`` connected to the same Zenoh router lists and echoes them
with no stereod package and no bridge. Humble's rmw_zenoh is not supported (no type hashes).

What it follows (read in rmw_zenoh's own source; paths under ``rmw_zenoh_cpp/src/detail/``
unless said): the releases ``0.2.10`` (Jazzy) and ``0.6.7`` (Kilted) of github ros2/rmw_zenoh,
as the ROS build farm imported them into ros2-gbp/rmw_zenoh-release (commits ``70d15597``
and ``a6ea04f6``, tags ``upstream/0.2.10`` and ``upstream/0.6.7``). Every file cited below is
the same blob in both; ``docs/ros2-foxglove.md`` lists the blob ids. The wire format is
unchanged from Jazzy 0.2.4 and Kilted 0.6.0 on: Jazzy 0.2.0 to 0.2.3 wrote an attachment of
named fields (``"sequence_number"``, ...), and 0.2.0 to 0.2.2 had transient local as the
default durability, so they are not spoken (nor are Humble's 0.1.x, nor the Zenoh 0.11 builds
of 2024 such as rolling ``bfc065f``).

* data key ``<domain_id>/<topic without its leading slash>/<pkg>::msg::dds_::<Type>_/RIHS01_<hex>``
  (``liveliness_utils.cpp``, ``TopicInfo::TopicInfo``; the type name from
  ``type_support_common.cpp``, ``_create_type_name``; the hash is rosidl's RIHS01 string);
* payload: CDR with its 4-byte encapsulation header, little-endian ``00 01 00 00``
  (``type_support.cpp``, ``serialize_encapsulation``);
* attachment (``attachment_helpers.cpp``, ``AttachmentData::serialize_to_zbytes``; the layout
  in ``docs/design.md``, "Publishers"): sequence number (int64 LE, from 1 per publisher),
  source timestamp (int64 LE, ns of the system clock at the put), then the GID as zenoh-ext
  serializes a ``std::array<uint8_t, 16>``: its length 16 in one byte, then the 16 bytes;
  33 bytes in all (``rmw_publisher_data.cpp``, ``PublisherData::publish``);
* GID: XXH3-128 (seed 0) of the entity's liveliness key expression, its low 64 bits then its
  high 64 bits, each little-endian (``liveliness_utils.cpp``, ``Entity::Entity``, with
  ``simplified_xxhash3.cpp``);
* liveliness tokens (``liveliness_utils.cpp``, ``Entity::Entity``):
  ``@ros2_lv/<domain>/<zid>/<nid>/<id>/NN/<enclave>/<namespace>/<node>`` for the node and, for
  a publisher, ``MP`` and ``/<topic>/<type>/<hash>/<qos>`` after the node; ``mangle_name``
  turns every ``/`` in the enclave, namespace, node, topic, type and hash into ``%`` (so the
  default enclave ``/`` and the root namespace are ``%``); ``<zid>`` is the session id as
  Zenoh prints it; ``<nid>`` and ``<id>`` come from one counter per session that starts at 0
  (``rmw_context_impl_s.cpp``, ``get_next_entity_id``): the node is 0/0 (``rmw_node_data.cpp``)
  and its publishers 0/1, 0/2, ...;
* QoS chunk ``<rel>:<dur>:<hist>,<depth>:<dl.s>,<dl.ns>:<ls.s>,<ls.ns>:<lv>,<lv.s>,<lv.ns>``
  (``qos_to_keyexpr``; ``rmw/types.h`` enum values), each field empty when it equals
  rmw_zenoh's default (``qos.cpp``: reliable, volatile, keep last, depth 42, infinite
  durations, automatic liveliness): data topics are reliable, volatile, keep last 10
  (``::,10:,:,:,,``), ``/tf_static`` transient local, keep last 1 (``:1:,1:,:,:,,``);
* publishers (``rmw_publisher_data.cpp``, ``PublisherData::make``): congestion control DROP,
  reliable; a transient-local one is a zenoh-ext AdvancedPublisher with a cache of ``depth``
  samples, publisher detection, and (being reliable) sample-miss detection with a sporadic
  heartbeat every 500 ms, which rmw_zenoh's transient-local subscriptions (an
  AdvancedSubscriber that detects late publishers, ``rmw_subscription_data.cpp``) query when
  they join. rmw_zenoh declares its volatile publishers as AdvancedPublishers with no option
  set, which put exactly as a plain publisher does; stereod uses a plain one for its matching
  listener.

Topics (``[ros2] topics``): ``odom`` (``nav_msgs/msg/Odometry`` per track state), ``markers``
(``visualization_msgs/msg/MarkerArray`` per message), ``camera_info`` (both eyes, each at its
own capture instant), ``images`` (``sensor_msgs/msg/CompressedImage`` of each eye, JPEG, encoded
only while a subscriber matches, at most ``daemon.image_rate_hz`` a second), ``tf_static`` and
``objects`` (the JSON as ``std_msgs/msg/String``). ``[ros2] namespace`` is the node's namespace
and prefixes the stereod topics (not ``/tf_static``, which tf2 reads at the root).
"""

from __future__ import annotations

import contextlib
import logging
import re
import struct
import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, Final

import cv2
import numpy as np
import zenoh
import zenoh.ext

from stereod.daemon.processing import Outgoing
from stereod.daemon.status import Health
from stereod.ros.mapping import RosMessage, RosMessages
from stereod.ros.names import cdr_encoder
from stereod.sources.frames import Eye
from stereod.vision.calibration import Calibration

log = logging.getLogger(__name__)

DISTROS: Final = ("jazzy", "kilted")
"""The ROS 2 distributions whose rmw_zenoh this module speaks."""

ADMIN_SPACE: Final = "@ros2_lv"
"""Prefix of rmw_zenoh's liveliness tokens (graph discovery)."""

TOPICS: Final = ("odom", "markers", "camera_info", "images", "tf_static", "objects")
"""The topic groups ``[ros2] topics`` can name."""

TYPE_HASHES: Final[dict[str, str]] = {
    "nav_msgs/msg/Odometry": (
        "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0"
    ),
    "visualization_msgs/msg/MarkerArray": (
        "RIHS01_86cb8800b6fb05b5eff1abd7a56f62a5641d3ae9a1c29e78e67e704f1d067dcf"
    ),
    "sensor_msgs/msg/CameraInfo": (
        "RIHS01_b3dfd68ff46c9d56c80fd3bd4ed22c7a4ddce8c8348f2f59c299e73118e7e275"
    ),
    "sensor_msgs/msg/CompressedImage": (
        "RIHS01_15640771531571185e2efc8a100baf923961a4d15d5569652e6cb6691e8e371a"
    ),
    "tf2_msgs/msg/TFMessage": (
        "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087"
    ),
    "std_msgs/msg/String": (
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
    ),
}
"""RIHS01 type hashes (REP 2011) of the published types in Jazzy and Kilted (the two agree for
these types); tests compare them with rosbags' ``hash_rihs01``."""

RMW_ZENOH_RELEASES: Final[dict[str, tuple[str, str]]] = {
    "jazzy": ("0.2.4", "0.2.10"),
    "kilted": ("0.6.0", "0.6.7"),
}
"""Per distribution, the first and the last rmw_zenoh_cpp release whose wire format this module
was checked against (the same format from the first to the last)."""

_GID_SIZE: Final = 16  # RMW_GID_STORAGE_SIZE (rmw/types.h) since Iron
# rmw_publisher_data.cpp: SAMPLE_MISS_DETECTION_HEARTBEAT_PERIOD, 500 ms.
_HEARTBEAT_S: Final = 0.5


@dataclass(frozen=True)
class Qos:
    """The QoS policies rmw_zenoh writes into a token (``rmw/types.h`` enum values): reliability
    1 reliable / 2 best effort, durability 1 transient local / 2 volatile, history 1 keep last /
    2 keep all, ``depth`` messages; deadline, lifespan and liveliness are left at defaults."""

    reliability: int = 1
    durability: int = 2
    history: int = 1
    depth: int = 10


RMW_ZENOH_DEFAULT_QOS: Final = Qos(reliability=1, durability=2, history=1, depth=42)
"""rmw_zenoh's defaults (``qos.cpp``): a token leaves out every field equal to them."""

DATA_QOS: Final = Qos()
"""QoS of the data topics: reliable, volatile, keep last 10 (rclcpp's default profile)."""

LATCHED_QOS: Final = Qos(durability=1, depth=1)
"""QoS of ``/tf_static``: reliable, transient local, keep last 1 (tf2's static broadcaster)."""


def dds_type_name(typename: str) -> str:
    """``pkg/msg/Type`` as rmw_zenoh's type support names it: ``pkg::msg::dds_::Type_``."""
    # type_support_common.cpp, _create_type_name: message_namespace_ ("pkg::msg") + "::dds_::"
    # + message_name_ + "_".
    pkg, kind, name = typename.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def mangle(name: str) -> str:
    """A ROS name as one key chunk: every ``/`` becomes ``%`` (rmw_zenoh's ``mangle_name``)."""
    # liveliness_utils.cpp, mangle_name: SLASH_REPLACEMENT '%', nothing else is escaped.
    return name.replace("/", "%")


def qos_keyexpr(qos: Qos) -> str:
    """The QoS chunk of a token (``qos_to_keyexpr``): each field empty at its default."""
    # liveliness_utils.cpp, qos_to_keyexpr: ':' between policies, ',' inside one; a field equal
    # to QoS::default_qos() (qos.cpp) is left empty. Deadline, lifespan and lease duration are
    # stereod's defaults, which best_available_qos turns into rmw_zenoh's (infinite): empty.
    d = RMW_ZENOH_DEFAULT_QOS

    def f(value: int, default: int) -> str:
        return "" if value == default else str(value)

    return (
        f"{f(qos.reliability, d.reliability)}:{f(qos.durability, d.durability)}:"
        f"{f(qos.history, d.history)},{f(qos.depth, d.depth)}:,:,:,,"
    )


def data_keyexpr(domain_id: int, topic: str, typename: str) -> str:
    """The key a topic's samples are put on: ``<domain>/<topic>/<dds type>/<type hash>``."""
    # liveliness_utils.cpp, TopicInfo::TopicInfo: domain "/" strip_slashes(name) "/" type "/"
    # hash (strip_slashes drops one leading and one trailing '/'; a ROS name has no other).
    return f"{domain_id}/{topic.strip('/')}/{dds_type_name(typename)}/{TYPE_HASHES[typename]}"


def node_token(domain_id: int, zid: str, namespace: str, node: str, enclave: str = "/") -> str:
    """The liveliness token of a node (entity ``NN``, node id and entity id 0)."""
    # liveliness_utils.cpp, Entity::Entity: the chunks joined by '/', enclave, namespace and
    # name mangled; rmw_node_data.cpp, NodeData::make: nid = id = the session's next entity id,
    # 0 for its first node (rmw_context_impl_s.cpp, next_entity_id_ starts at 0).
    return (
        f"{ADMIN_SPACE}/{domain_id}/{zid}/0/0/NN/{mangle(enclave)}/{mangle(namespace)}/"
        f"{mangle(node)}"
    )


def publisher_token(
    domain_id: int,
    zid: str,
    entity_id: int,
    namespace: str,
    node: str,
    topic: str,
    typename: str,
    qos: Qos,
    enclave: str = "/",
) -> str:
    """The liveliness token of a publisher (entity ``MP``) of node 0."""
    # rmw_publisher_data.cpp, PublisherData::make: Entity::make(zid, node id, publisher id,
    # Publisher, node info, TopicInfo{domain, topic, type name, hash, adapted QoS}); Entity::
    # Entity appends mangle_name(topic), mangle_name(type), mangle_name(hash), qos_to_keyexpr.
    return (
        f"{ADMIN_SPACE}/{domain_id}/{zid}/0/{entity_id}/MP/{mangle(enclave)}/{mangle(namespace)}/"
        f"{mangle(node)}/{mangle(topic)}/{dds_type_name(typename)}/{TYPE_HASHES[typename]}/"
        f"{qos_keyexpr(qos)}"
    )


def xxh3_gid(data: bytes) -> bytes:
    """16 bytes of XXH3-128 (seed 0, default secret) of ``data``: the low 64 bits then the
    high 64 bits, each little-endian, as rmw_zenoh lays out a GID."""
    # liveliness_utils.cpp, Entity::Entity: memcpy(gid, &low64, 8); memcpy(gid + 8, &high64, 8)
    # of simplified_XXH3_128bits (simplified_xxhash3.cpp: xxHash's XXH3_128bits, portable code);
    # memcpy of a uint64_t is little-endian on every platform ROS 2 supports.
    import xxhash

    value = xxhash.xxh3_128_intdigest(data)
    return (value & (2**64 - 1)).to_bytes(8, "little") + (value >> 64).to_bytes(8, "little")


def entity_gid(token: str) -> bytes:
    """The 16-byte GID rmw_zenoh gives an entity: :func:`xxh3_gid` of its liveliness token's
    key expression (UTF-8), the same in Jazzy and Kilted; it is the attachment's source GID."""
    return xxh3_gid(token.encode())


def attachment(sequence_number: int, source_timestamp_ns: int, gid: bytes) -> bytes:
    """rmw_zenoh's attachment of a sample: int64 sequence number, int64 source timestamp (ns),
    then the GID as a length-prefixed byte sequence (zenoh-ext serialization, little-endian)."""
    # attachment_helpers.cpp, AttachmentData::serialize_to_zbytes: serialize(int64_t seq),
    # serialize(int64_t timestamp), serialize(std::array<uint8_t, 16> gid); docs/design.md,
    # "Publishers": 8 + 8 bytes little-endian, 1 byte for the GID's length (16), 16 bytes.
    # zenoh-cpp (ext/serialization.hxx) writes a std::array as a sequence, its LEB128 length
    # then each element, and its deserializer refuses a length other than 16.
    if len(gid) != _GID_SIZE:
        raise ValueError(f"a GID is {_GID_SIZE} bytes, got {len(gid)}")
    return struct.pack("<qqB", sequence_number, source_timestamp_ns, _GID_SIZE) + gid


def node_name(rig: str) -> str:
    """The node's name, ``stereod_<rig>`` (characters a ROS name does not allow become ``_``)."""
    return "stereod_" + re.sub(r"[^A-Za-z0-9_]", "_", rig)


def node_namespace(namespace: str) -> str:
    """``[ros2] namespace`` as a ROS namespace: ``/`` when empty, else ``/<ns>``."""
    ns = namespace.strip("/")
    return f"/{ns}" if ns else "/"


class _Endpoint:
    """One ROS publisher: a Zenoh (advanced) publisher, its liveliness token and its counter."""

    def __init__(
        self,
        session: zenoh.Session,
        *,
        domain_id: int,
        entity_id: int,
        namespace: str,
        node: str,
        topic: str,
        typename: str,
        qos: Qos,
    ) -> None:
        self.topic = topic
        self.typename = typename
        self.key = data_keyexpr(domain_id, topic, typename)
        zid = str(session.zid())
        self.token_key = publisher_token(
            domain_id, zid, entity_id, namespace, node, topic, typename, qos
        )
        self.gid = entity_gid(self.token_key)
        self.encode = cdr_encoder(typename)
        self.sequence = 1  # PublisherData: sequence_number_(1), post-incremented at each put
        self.matching = False
        self._listener: Any = None
        # rmw_publisher_data.cpp, PublisherData::make: congestion control DROP, but BLOCK for
        # reliable + keep all; reliability RELIABLE or BEST_EFFORT, always set explicitly.
        reliable = qos.reliability == 1
        reliability = zenoh.Reliability.RELIABLE if reliable else zenoh.Reliability.BEST_EFFORT
        congestion = (
            zenoh.CongestionControl.BLOCK
            if reliable and qos.history == 2
            else zenoh.CongestionControl.DROP
        )
        self._pub: Any
        if qos.durability == 1:
            # Transient local: publisher detection and a cache of `depth` samples; reliable,
            # also sample-miss detection with a sporadic heartbeat (500 ms) so subscribers
            # recover missed samples from the cache (no timestamping needed on the session).
            miss = (
                zenoh.ext.MissDetectionConfig(heartbeat=None, sporadic_heartbeat=_HEARTBEAT_S)
                if reliable
                else None
            )
            self._pub = zenoh.ext.declare_advanced_publisher(
                session,
                self.key,
                congestion_control=congestion,
                reliability=reliability,
                cache=zenoh.ext.CacheConfig(max_samples=qos.depth),
                sample_miss_detection=miss,
                publisher_detection=True,
            )
        else:
            pub = session.declare_publisher(
                self.key, congestion_control=congestion, reliability=reliability
            )
            self._pub = pub
            self._listener = pub.declare_matching_listener(self._on_matching)
            self.matching = bool(pub.matching_status.matching)  # type: ignore[attr-defined]
        self._token = session.liveliness().declare_token(self.token_key)

    def _on_matching(self, status: zenoh.MatchingStatus) -> None:
        self.matching = bool(status.matching)
        log.info("ros2: %s %s", self.topic, "subscribed" if status.matching else "unsubscribed")

    def put(self, body: dict[str, Any]) -> None:
        """CDR-encode ``body`` and put it with rmw_zenoh's attachment."""
        # PublisherData::publish: source timestamp = get_system_time_in_ns() (zenoh_utils.cpp,
        # std::chrono::system_clock), taken just before the put.
        att = attachment(self.sequence, time.time_ns(), self.gid)
        self.sequence += 1
        self._pub.put(self.encode(body), attachment=att)

    def close(self) -> None:
        for entity in (self._token, self._listener, self._pub):
            if entity is not None:
                with contextlib.suppress(zenoh.ZError):  # the session is already closed
                    entity.undeclare()


class Ros2Live:
    """Publishes one rig's run as the ROS 2 node ``<namespace>/stereod_<rig>`` on ``session``.

    ``topics`` names the groups to publish (see :data:`TOPICS`); ``domain_id`` is
    ``ROS_DOMAIN_ID``; ``calibration`` gives ``/tf_static`` and camera_info (for the canonical
    rig, ``vision.calibration.canonical``). The output thread calls :meth:`offer` for each
    published pair; it never raises (a failure counts as ``ros2_error`` in ``health``).
    """

    def __init__(
        self,
        session: zenoh.Session,
        rig: str,
        *,
        calibration: Calibration,
        domain_id: int = 0,
        namespace: str = "",
        topics: Iterable[str] = ("odom", "markers", "camera_info", "images", "tf_static"),
        image_rate_hz: float = 5.0,
        jpeg_quality: int = 80,
        health: Health | None = None,
    ) -> None:
        self.rig = rig
        self.domain_id = domain_id
        self.namespace = node_namespace(namespace)
        self.node = node_name(rig)
        self.topics = frozenset(topics)
        self.health = health
        self.ros = RosMessages(rig, calibration=calibration)
        self.names = self.ros.names
        self.period_s = 1.0 / image_rate_hz if image_rate_hz > 0 else float("inf")
        self._quality = [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)]
        self._next_image_s = 0.0
        self._lock = threading.Lock()
        self.published: dict[str, int] = {}
        self.errors = 0
        zid = str(session.zid())
        self.node_token_key = node_token(domain_id, zid, self.namespace, self.node)
        self._node_token: Any = session.liveliness().declare_token(self.node_token_key)
        self._endpoints: dict[str, _Endpoint] = {}
        for topic, typename, qos in self._wanted():
            self._endpoints[topic] = _Endpoint(
                session,
                domain_id=domain_id,
                entity_id=len(self._endpoints) + 1,
                namespace=self.namespace,
                node=self.node,
                topic=topic,
                typename=typename,
                qos=qos,
            )
        if "tf_static" in self.topics:
            tf = self.ros.tf_static(time.time_ns())
            if tf is not None:
                self._put(tf)

    def topic(self, name: str) -> str:
        """A stereod topic under ``[ros2] namespace`` (``/tf_static`` stays at the root)."""
        if name == self.names.tf_static_topic or self.namespace == "/":
            return name
        return self.namespace + name

    def _wanted(self) -> list[tuple[str, str, Qos]]:
        n, t = self.names, self.topics
        out: list[tuple[str, str, Qos]] = []
        if "tf_static" in t:
            out.append((n.tf_static_topic, "tf2_msgs/msg/TFMessage", LATCHED_QOS))
        if "odom" in t:
            out.append((self.topic(n.odom_topic), "nav_msgs/msg/Odometry", DATA_QOS))
        if "markers" in t:
            out.append(
                (self.topic(n.markers_topic), "visualization_msgs/msg/MarkerArray", DATA_QOS)
            )
        for eye in Eye:
            if "camera_info" in t:
                out.append(
                    (self.topic(n.camera_info_topic(eye)), "sensor_msgs/msg/CameraInfo", DATA_QOS)
                )
            if "images" in t:
                out.append(
                    (self.topic(n.image_topic(eye)), "sensor_msgs/msg/CompressedImage", DATA_QOS)
                )
        if "objects" in t:
            out.append((self.topic(n.objects_topic), "std_msgs/msg/String", DATA_QOS))
        return out

    @property
    def endpoints(self) -> dict[str, _Endpoint]:
        """The publishers by ROS topic name."""
        return dict(self._endpoints)

    def set_geometry(self, calibration: Calibration) -> None:
        """Use ``calibration`` for camera_info from the next pair on, and send ``/tf_static``
        again (a reload brought a new calibration)."""
        with self._lock:
            self.ros.set_geometry(calibration)
            if "tf_static" in self.topics:
                tf = self.ros.tf_static(time.time_ns())
                if tf is not None:
                    self._put(tf)

    def images_wanted(self) -> bool:
        """Whether some ROS subscriber matches an image topic now."""
        return any(
            e.matching for e in self._endpoints.values() if e.typename.endswith("CompressedImage")
        )

    def _put(self, m: RosMessage) -> None:
        endpoint = self._endpoints.get(self.topic(m.topic))
        if endpoint is None:
            return
        endpoint.put(m.body)
        self.published[endpoint.topic] = self.published.get(endpoint.topic, 0) + 1

    def offer(self, item: Outgoing) -> None:
        """Publish one pair's messages (output thread); never raises."""
        try:
            with self._lock:
                self._publish(item)
        except Exception as exc:  # ROS output must never stop the daemon
            self.errors += 1
            if self.health is not None:
                self.health.error("ros2_error")
                self.health.problem(f"ros2: publishing failed: {exc}", "ros2_error")
            log.debug("ros2 publish failed", exc_info=True)

    def _publish(self, item: Outgoing) -> None:
        msg = item.message
        if msg is None:
            return
        for m in self.ros.objects(msg):
            if not m.topic.endswith("/speed_heading"):
                self._put(m)
        stamps = eye_stamps(item)
        for eye in Eye:
            info = self.ros.camera_info(eye, stamps[eye])
            if info is not None:
                self._put(info)
        pair = item.pair
        now = time.monotonic()
        if pair is None or now < self._next_image_s or not self.images_wanted():
            return
        self._next_image_s = now + self.period_s
        for eye, frame in ((Eye.LEFT, pair.left), (Eye.RIGHT, pair.right)):
            topic = self.names.image_topic(eye)
            endpoint = self._endpoints.get(self.topic(topic))
            if endpoint is None or not endpoint.matching:
                continue
            ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(frame.image), self._quality)
            if ok:
                self._put(
                    self.ros.compressed_image(
                        topic, self.names.eye_frame(eye), "jpeg", buf.tobytes(), stamps[eye]
                    )
                )

    def close(self) -> None:
        """Clear the markers (a DELETEALL: a viewer would show the last tracks until they
        expire), then withdraw the publishers and the node from the ROS graph (idempotent)."""
        with self._lock:
            if self._endpoints:
                with contextlib.suppress(Exception):  # (the session may be closed already)
                    self._put(self.ros.delete_all_markers(time.time_ns()))
            endpoints = list(self._endpoints.values())
            self._endpoints.clear()
            token, self._node_token = self._node_token, None
        for e in endpoints:
            e.close()
        if token is not None:
            with contextlib.suppress(zenoh.ZError):
                token.undeclare()

    def __enter__(self) -> Ros2Live:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def eye_stamps(item: Outgoing) -> dict[Eye, int]:
    """Each eye's capture instant (UTC, ns) of one pair: its frame's ``t_ns`` plus the message's
    UTC offset, as the MCAP export stamps frames; the message's stamp when the frames are not
    kept."""
    msg = item.message
    assert msg is not None
    if item.pair is None:
        return {Eye.LEFT: msg.stamp_utc_ns, Eye.RIGHT: msg.stamp_utc_ns}
    offset = msg.stamp_utc_ns - msg.t_ns
    return {Eye.LEFT: item.pair.left.t_ns + offset, Eye.RIGHT: item.pair.right.t_ns + offset}
