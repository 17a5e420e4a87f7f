"""ROS 2 live (stereod.ros.ros2_live) checked against rmw_zenoh and rosbags, not against itself.

The literals below are copied from ros2/rmw_zenoh's releases as ros2-gbp/rmw_zenoh-release
imported them (git tags ``upstream/<version>``): 0.2.10 (Jazzy, commit 70d155975adf) and 0.6.7
(Kilted, commit a6ea04f606ee), whose ``docs/design.md`` is the same blob f3b127990f4b, and the
earlier 0.2.5-0.2.9 and 0.6.2-0.6.6, whose ``docs/design.md`` (blob 9db7a92) wrote the same
examples with domain 2. The live test's subscriber is written from that design: it discovers
entities through the ``@ros2_lv/<domain>/**`` liveliness tokens as rmw_zenoh's graph cache
does, checks them as ``Entity::make(keyexpr)`` and ``keyexpr_to_qos`` parse them, builds the
data key from the token's parts as ``TopicInfo`` does, decodes the attachment by the byte
layout the design document gives and the payload with rosbags' own Jazzy definitions.
"""

from __future__ import annotations

import math
import struct
import threading
import time
from typing import Any

import cv2
import numpy as np
import pytest
import zenoh
import zenoh.ext
from rosbags.typesys import Stores, get_typestore

from stereod.daemon.config import environment, load_config
from stereod.daemon.daemon import Daemon
from stereod.ros import ros2_live
from stereod.ros.mapping import RosMessages
from stereod.ros.names import cdr_encoder
from stereod.sources.frames import Eye
from stereod.vision.calibration import canonical
from stereod_fakes.synth import SyntheticDriver

from .conftest import zenoh_config

STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
# docs/design.md of 0.2.10 / 0.6.7 (blob f3b127990f4b), "Topic and Service name mapping to
# Zenoh key expressions", examples using demo_nodes_cpp:
DESIGN_KEY = "0/chatter/std_msgs::msg::dds_::String_/" + STRING_HASH
DESIGN_KEY_NS = "0/robot1/chatter/std_msgs::msg::dds_::String_/" + STRING_HASH
# ... and "Graph Cache", examples using the demo_nodes_cpp package (ROS_DOMAIN_ID=0):
DESIGN_NN = "@ros2_lv/0/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
DESIGN_MS = (
    "@ros2_lv/0/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/"
    "std_msgs::msg::dds_::String_/"
    "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/::,10:,:,:,,"
)
DESIGN_MP = (
    "@ros2_lv/0/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
    "std_msgs::msg::dds_::String_/"
    "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/::,7:,:,:,,"
)
# docs/design.md of 0.2.5-0.2.9 / 0.6.2-0.6.6 (blob 9db7a92), the same examples in domain 2:
DESIGN_NN_2 = "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
DESIGN_MP_2 = (
    "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
    "std_msgs::msg::dds_::String_/"
    "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/::,7:,:,:,,"
)
# docs/design.md, "Publishers": "8 bytes for the sequence number (int64_t), encoded as a
# little-endian; 8 bytes for the timestamp (number of ns since UNIX EPOCH as int64_t), encoded
# as a little-endian; 1 byte for the length of the publisher GID (currently always 16); 16 bytes
# for the publisher GID".
DESIGN_ATTACHMENT = struct.Struct("<qqB16s")
# rclcpp's default profile (keep last 10, reliable, volatile) as the listener's subscription
# token above writes it:
DEFAULT_PROFILE_QOS = DESIGN_MS.rsplit("/", 1)[1]

# xxHash's own XXH3_128bits test vectors, seed 0 (github Cyan4973/xxHash, commit 08ae0257300d,
# cli/xsum_sanity_check.c, XSUM_XXH128_testdata: {len, seed, {low64, high64}}), over the buffer
# XSUM_fillTestBuffer makes; the lengths cover each of XXH3's code paths (0, 1-3, 4-8, 9-16,
# 17-128, 129-240 and the long loop), as a token's length does.
XXH128_VECTORS = [
    (0, 0x6001C324468D497F, 0x99AA06D3014798D8),
    (1, 0xC44BDFF4074EECDB, 0xA6CD5E9392000F6A),
    (6, 0x3E7039BDDA43CFC6, 0x082AFE0B8162D12A),
    (12, 0x061A192713F69AD9, 0x6E3EFD8FC7802B18),
    (24, 0x1E7044D28B1B901D, 0x0CE966E4678D3761),
    (48, 0xF942219AED80F67B, 0xA002AC4E5478227E),
    (81, 0x5E8BAFB9F95FB803, 0x4952F58181AB0042),
    (222, 0xF1AEBD597CEC6B3A, 0x337E09641B948717),
    (403, 0xCDEB804D65C6DEA4, 0x1B6DE21E332DD73D),
    (512, 0x617E49599013CB6B, 0x18D2D110DCC9BCA1),
    (2048, 0xDD59E2C3A5F038E0, 0xF736557FD47073A5),
    (2240, 0x6E73A90539CF2948, 0xCCB134FBFA7CE49D),
    (2367, 0xCB37AEB9E5D361ED, 0xE89C0F6FF369B427),
]


def xsum_test_buffer(n: int) -> bytes:
    """xxHash's XSUM_fillTestBuffer: byte i is the top byte of PRIME32 * PRIME64^i (mod 2^64)."""
    out, gen = bytearray(), 2654435761
    for _ in range(n):
        out.append(gen >> 56)
        gen = (gen * 11400714785074694797) % 2**64
    return bytes(out)


TYPES = [
    "nav_msgs/msg/Odometry",
    "visualization_msgs/msg/MarkerArray",
    "sensor_msgs/msg/CameraInfo",
    "sensor_msgs/msg/CompressedImage",
    "tf2_msgs/msg/TFMessage",
    "std_msgs/msg/String",
]


@pytest.mark.parametrize("store", [Stores.ROS2_JAZZY, Stores.ROS2_KILTED])
def test_type_hashes_are_those_rosbags_computes(store: Stores) -> None:
    ts = get_typestore(store)
    for t in TYPES:
        assert ros2_live.TYPE_HASHES[t] == ts.hash_rihs01(t), t


@pytest.mark.parametrize(
    ("domain", "nn", "mp"), [(0, DESIGN_NN, DESIGN_MP), (2, DESIGN_NN_2, DESIGN_MP_2)]
)
def test_tokens_match_rmw_zenoh_design_examples(domain: int, nn: str, mp: str) -> None:
    assert ros2_live.node_token(domain, "aac3178e146ba6f1fc6e6a4085e77f21", "/", "listener") == nn
    token = ros2_live.publisher_token(
        domain,
        "8b20917502ee955ac4476e0266340d5c",
        10,
        "/",
        "talker",
        "/chatter",
        "std_msgs/msg/String",
        ros2_live.Qos(depth=7),
    )
    assert token == mp


def test_keys_qos_and_hash_match_rmw_zenoh_design_examples() -> None:
    assert ros2_live.data_keyexpr(0, "/chatter", "std_msgs/msg/String") == DESIGN_KEY
    assert ros2_live.data_keyexpr(0, "/robot1/chatter", "std_msgs/msg/String") == DESIGN_KEY_NS
    assert ros2_live.TYPE_HASHES["std_msgs/msg/String"] == STRING_HASH
    # stereod's data topics have rclcpp's default profile, as the listener's subscription.
    assert ros2_live.qos_keyexpr(ros2_live.DATA_QOS) == DEFAULT_PROFILE_QOS == "::,10:,:,:,,"
    # A namespaced node: every '/' of a name becomes '%'.
    node = ros2_live.node_token(0, "ab", "/lab/robot1", "stereod_minoru")
    assert node == "@ros2_lv/0/ab/0/0/NN/%/%lab%robot1/stereod_minoru"


@pytest.mark.parametrize(
    ("n", "low64", "high64"), XXH128_VECTORS, ids=[f"len{v[0]}" for v in XXH128_VECTORS]
)
def test_gid_is_xxh3_128_low_then_high_little_endian(n: int, low64: int, high64: int) -> None:
    """rmw_zenoh's GID layout (Entity::Entity: memcpy of low64, then of high64) of XXH3-128,
    against xxHash's own test vectors."""
    data = xsum_test_buffer(n)
    assert ros2_live.xxh3_gid(data) == struct.pack("<QQ", low64, high64)


def test_gid_of_an_entity_is_that_of_its_token() -> None:
    token = DESIGN_MP
    assert ros2_live.entity_gid(token) == ros2_live.xxh3_gid(token.encode("utf-8"))
    assert ros2_live.entity_gid(DESIGN_MP) != ros2_live.entity_gid(DESIGN_MP_2)


@pytest.mark.parametrize(
    ("qos", "reliability", "congestion"),
    [
        (ros2_live.Qos(), "RELIABLE", "DROP"),
        (ros2_live.Qos(reliability=2), "BEST_EFFORT", "DROP"),
        (ros2_live.Qos(history=2), "RELIABLE", "BLOCK"),
        (ros2_live.Qos(reliability=2, history=2), "BEST_EFFORT", "DROP"),
    ],
)
def test_publisher_options_follow_rmw_zenoh(
    listener: zenoh.Session, qos: ros2_live.Qos, reliability: str, congestion: str
) -> None:
    """rmw_publisher_data.cpp, PublisherData::make: DROP unless reliable + keep all (BLOCK);
    the reliability is set either way."""
    end = ros2_live._Endpoint(
        listener,
        domain_id=0,
        entity_id=1,
        namespace="/",
        node="n",
        topic="/t",
        typename="std_msgs/msg/String",
        qos=qos,
    )
    try:
        assert end._pub.reliability == getattr(zenoh.Reliability, reliability)
        assert end._pub.congestion_control == getattr(zenoh.CongestionControl, congestion)
    finally:
        end.close()


def test_attachment_is_the_design_layout_and_zenoh_ext_serialization() -> None:
    gid = bytes(range(16))
    att = ros2_live.attachment(7, 1_700_000_000_123_456_789, gid)
    assert len(att) == 33
    assert DESIGN_ATTACHMENT.unpack(att) == (7, 1_700_000_000_123_456_789, 16, gid)
    # rmw_zenoh writes it with zenoh-ext's serializer: (int64, int64, byte sequence).
    ext = zenoh.ext.z_serialize(
        (zenoh.ext.Int64(7), zenoh.ext.Int64(1_700_000_000_123_456_789), gid)
    )
    assert att == ext.to_bytes()


def test_payloads_deserialize_with_rosbags_jazzy_definitions() -> None:
    jazzy = get_typestore(Stores.ROS2_JAZZY)
    cal = canonical(0.06, 60.0, 320, 240)
    ros = RosMessages("minoru", calibration=cal)
    tf = ros.tf_static(1_700_000_000_000_000_000)
    assert tf is not None
    info = ros.camera_info(Eye.RIGHT, 1_700_000_000_002_000_000)
    assert info is not None
    image = ros.compressed_image("/x", "f", "jpeg", b"\xff\xd8\xff", 5)
    for m in [tf, info, image]:
        data = cdr_encoder(m.typename)(m.body)
        assert data[:4] == b"\x00\x01\x00\x00"  # CDR little-endian encapsulation
        got = jazzy.deserialize_cdr(data, m.typename)
        assert got is not None
    got = jazzy.deserialize_cdr(cdr_encoder(tf.typename)(tf.body), tf.typename)
    assert [t.child_frame_id for t in got.transforms] == [
        "stereod_minoru_optical",
        "stereod_minoru_left_optical",
        "stereod_minoru_right_optical",
    ]
    assert got.transforms[2].transform.translation.x == pytest.approx(0.03)
    got = jazzy.deserialize_cdr(cdr_encoder(info.typename)(info.body), info.typename)
    assert (got.width, got.height, got.header.stamp.nanosec) == (320, 240, 2_000_000)


# -- the live check: a subscriber written from rmw_zenoh's design ---------------------------


def _parse_token(key: str) -> dict[str, Any]:
    """liveliness_utils.cpp Entity::make(keyexpr): split on '/', no chunk empty, 9 chunks for
    a node and 13 for a publisher; demangle '%' to '/'; keyexpr_to_qos: 6 policies split on
    ':', history, deadline and lifespan of 2 fields and liveliness of 3, split on ','."""
    parts = key.split("/")
    assert all(parts) and len(parts) == {"NN": 9, "MP": 13}[parts[5]], key
    if parts[5] == "MP":
        policies = parts[12].split(":")
        assert [len(p.split(",")) for p in policies] == [1, 1, 2, 2, 2, 3], key
    names = ["admin", "domain", "zid", "nid", "id", "kind", "enclave", "ns", "node"]
    names += ["topic", "type", "hash", "qos"]
    out: dict[str, Any] = dict(zip(names, parts, strict=False))
    out["key"] = key
    for k in ("enclave", "ns", "node", "topic", "type", "hash"):
        if k in out:
            out[k] = out[k].replace("%", "/")
    return out


def _graph(session: zenoh.Session, domain: int, want: int, timeout: float) -> list[dict]:
    """The graph as rmw_zenoh's context builds it at start: liveliness_get on the domain."""
    deadline = time.monotonic() + timeout
    while True:
        replies = list(session.liveliness().get(f"@ros2_lv/{domain}/**", timeout=2))
        tokens = [_parse_token(str(r.ok.key_expr)) for r in replies if r.ok is not None]
        if len(tokens) >= want or time.monotonic() > deadline:
            return tokens
        time.sleep(0.2)


def test_a_ros_subscriber_discovers_the_node_and_decodes_its_data(
    endpoint: str, listener: zenoh.Session
) -> None:
    jazzy = get_typestore(Stores.ROS2_JAZZY)
    cfg = load_config(
        overrides={
            "zenoh": {"connect": [endpoint]},
            "ros2": {"enabled": True, "domain_id": 3},
            "daemon": {"image_rate_hz": 50.0},
        }
    )
    scene = {"duration_s": 6.0, "fps": 15, "skew_s": 0.005}  # the right eye 5 ms late
    daemon = Daemon(cfg, SyntheticDriver(scene), rate=1.0)
    out: dict[str, Any] = {}
    thread = threading.Thread(target=lambda: out.setdefault("summary", daemon.run()))
    thread.start()
    got: dict[str, list[tuple[tuple, Any]]] = {"odom": [], "image": [], "info": [], "left": []}
    subs: list[Any] = []
    markers: list[Any] = []  # (kept until the daemon has stopped)
    cleared: list[zenoh.Sample] = []
    try:
        tokens = _graph(listener, 3, want=8, timeout=15)
        nodes = [t for t in tokens if t["kind"] == "NN"]
        assert [(n["ns"], n["node"], n["nid"], n["id"]) for n in nodes] == [
            ("/", "stereod_minoru", "0", "0")
        ]
        pubs = {t["topic"]: t for t in tokens if t["kind"] == "MP"}
        # No per-track topics: a publisher and a token per track would pile up in the graph.
        assert not [t for t in pubs if t.endswith("/speed_heading")]
        odom = pubs["/stereod/minoru/tracks/odom"]
        assert odom["type"] == "nav_msgs::msg::dds_::Odometry_"
        assert odom["hash"] == jazzy.hash_rihs01("nav_msgs/msg/Odometry")
        assert odom["qos"] == DEFAULT_PROFILE_QOS and odom["zid"] == nodes[0]["zid"]
        tf = pubs["/tf_static"]
        assert tf["qos"].split(":")[1] == "1"  # transient local

        def key(t: dict[str, Any]) -> str:  # TopicInfo: domain/topic/type/hash
            return f"{t['domain']}/{t['topic'].strip('/')}/{t['type']}/{t['hash']}"

        def collect(name: str) -> Any:
            def on(sample: zenoh.Sample) -> None:
                att = sample.attachment
                assert att is not None, "rmw_zenoh drops a sample without attachment"
                got[name].append((DESIGN_ATTACHMENT.unpack(att.to_bytes()), sample))

            return on

        subs.append(listener.declare_subscriber(key(odom), collect("odom")))
        markers_key = key(pubs["/stereod/minoru/tracks/markers"])
        markers.append(listener.declare_subscriber(markers_key, lambda s: cleared.append(s)))
        image = pubs["/stereod/minoru/right/image/compressed"]
        subs.append(listener.declare_subscriber(key(image), collect("image")))
        info = pubs["/stereod/minoru/right/camera_info"]
        subs.append(listener.declare_subscriber(key(info), collect("info")))
        left_info = pubs["/stereod/minoru/left/camera_info"]
        subs.append(listener.declare_subscriber(key(left_info), collect("left")))
        # A transient-local subscription joining late: rmw_zenoh's AdvancedSubscriber that
        # detects late publishers and queries their caches.
        statics: list[Any] = []
        subs.append(
            zenoh.ext.declare_advanced_subscriber(
                listener,
                key(tf),
                statics.append,
                history=zenoh.ext.HistoryConfig(detect_late_publishers=True),
            )
        )
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and not (
            len(got["odom"]) >= 3 and got["image"] and got["info"] and statics
        ):
            time.sleep(0.1)
    finally:
        for s in subs:
            s.undeclare()
        daemon.stop()
        thread.join(20)
        time.sleep(0.2)
        for s in markers:
            s.undeclare()
    assert not thread.is_alive()
    # The daemon gone, its markers are cleared: the last MarkerArray is one DELETEALL.
    assert cleared, "no MarkerArray arrived"
    array = "visualization_msgs/msg/MarkerArray"
    last = jazzy.deserialize_cdr(cleared[-1].payload.to_bytes(), array)
    assert [m.action for m in last.markers] == [3]
    assert statics, "no /tf_static for a late transient-local subscriber"
    tfm = jazzy.deserialize_cdr(statics[0].payload.to_bytes(), "tf2_msgs/msg/TFMessage")
    assert len(tfm.transforms) == 3
    assert len(got["odom"]) >= 3, "no Odometry arrived"
    seqs = [a[0] for a, _ in got["odom"]]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
    # The source GID is XXH3-128 of the publisher's token as discovered (Entity::Entity).
    odom_gid = ros2_live.xxh3_gid(odom["key"].encode())
    for (seq, ts, n, gid), sample in got["odom"]:
        assert n == 16 and gid == odom_gid and seq >= 1
        assert abs(ts - time.time_ns()) < 120e9
        msg = jazzy.deserialize_cdr(sample.payload.to_bytes(), "nav_msgs/msg/Odometry")
        assert msg.header.frame_id == "stereod_minoru_optical"
        assert msg.child_frame_id.startswith("stereod_minoru_track_")
        assert all(math.isfinite(v) for v in (msg.pose.pose.position.x, msg.pose.pose.position.z))
    # Images only once someone subscribed; each is a JPEG of the eye's size.
    (_, _, _, _), sample = got["image"][0]
    img = jazzy.deserialize_cdr(sample.payload.to_bytes(), "sensor_msgs/msg/CompressedImage")
    assert img.format == "jpeg" and img.header.frame_id == "stereod_minoru_right_optical"
    pic = cv2.imdecode(np.frombuffer(bytes(img.data), np.uint8), cv2.IMREAD_UNCHANGED)
    (_, _, _, _), sample = got["info"][0]
    info_msg = jazzy.deserialize_cdr(sample.payload.to_bytes(), "sensor_msgs/msg/CameraInfo")
    assert pic is not None and pic.shape[:2] == (info_msg.height, info_msg.width)

    # Each eye at its own capture instant: the right eye's camera_info 5 ms after the left's.
    def stamps(name: str) -> set[int]:
        out = set()
        for _, sample in got[name]:
            h = jazzy.deserialize_cdr(sample.payload.to_bytes(), "sensor_msgs/msg/CameraInfo")
            out.add(h.header.stamp.sec * 1_000_000_000 + h.header.stamp.nanosec)
        return out

    left, right = stamps("left"), stamps("info")
    assert len(left & {r - 5_000_000 for r in right}) >= 3
    assert not left & right
    assert daemon.ros2 is not None and daemon.ros2.errors == 0


def test_namespace_prefixes_node_and_topics_but_not_tf_static(listener: zenoh.Session) -> None:
    """``[ros2] namespace``: the node's namespace, mangled in its tokens, and the prefix of
    stereod's topics; ``/tf_static`` stays at the root, where tf2 reads it."""
    cal = canonical(0.06, 60.0, 320, 240)
    with ros2_live.Ros2Live(listener, "minoru", calibration=cal, namespace="lab/bench") as ros:
        assert ros.node_token_key.endswith("/0/0/NN/%/%lab%bench/stereod_minoru")
        topics = set(ros.endpoints)
        assert "/tf_static" in topics and "/lab/bench/stereod/minoru/tracks/odom" in topics
        odom = ros.endpoints["/lab/bench/stereod/minoru/tracks/odom"]
        assert odom.key.startswith("0/lab/bench/stereod/minoru/tracks/odom/nav_msgs::")
        assert "/MP/%/%lab%bench/stereod_minoru/%lab%bench%stereod%minoru%tracks%odom/" in (
            odom.token_key
        )
        replies = list(listener.liveliness().get("@ros2_lv/0/**", timeout=2))
        assert len(replies) == 1 + len(topics)


def test_ros2_section_from_the_environment() -> None:
    env = {"STEREOD_ROS2__ENABLED": "true", "STEREOD_ROS2__TOPICS": '["odom", "tf_static"]'}
    cfg = load_config(overrides=environment(env))
    assert cfg.ros2.enabled and cfg.ros2.topics == ["odom", "tf_static"]
    assert not load_config().ros2.enabled  # off unless asked for


# zenoh_security_tools/src/config_generator.cpp of 0.2.10 and 0.6.7 (the same functions):
# the key expressions rmw_zenoh's access-control generator allows for a topic ``name`` (its
# leading '/' removed, check_name) in domain ``d``: to_key_exprs, to_adv_pub_queryable_key_exprs
# and the liveliness tokens' "@ros2_lv/" + domain + "/**".
ACL_DATA = "{d}/{name}/*/*"
ACL_ADV_PUB = "{d}/{name}/*/*/@adv/pub/*/*/_"
ACL_LIVELINESS = "@ros2_lv/{d}/**"


def test_keys_fall_within_what_rmw_zenohs_access_control_allows(
    endpoint: str, listener: zenoh.Session
) -> None:
    """A lab that generates its Zenoh access control with zenoh_security_tools lets stereod's
    publications, tokens and the transient-local cache through: every key stereod declares
    lies within the patterns generated for its topics."""
    cal = canonical(0.06, 60.0, 320, 240)
    with (
        zenoh.open(zenoh_config(connect=[endpoint])) as session,
        ros2_live.Ros2Live(session, "minoru", calibration=cal, domain_id=5) as ros,
    ):
        for topic, end in ros.endpoints.items():
            name = topic.removeprefix("/")
            assert zenoh.KeyExpr(ACL_DATA.format(d=5, name=name)).includes(zenoh.KeyExpr(end.key))
            allowed = zenoh.KeyExpr(ACL_LIVELINESS.format(d=5))
            assert allowed.includes(zenoh.KeyExpr(end.token_key))
        assert zenoh.KeyExpr(ACL_LIVELINESS.format(d=5)).includes(zenoh.KeyExpr(ros.node_token_key))
        # The AdvancedPublisher of /tf_static: its detection token and its cache's queryable.
        pattern = ACL_ADV_PUB.format(d=5, name="tf_static")
        deadline = time.monotonic() + 10
        tokens: list[Any] = []
        while not tokens and time.monotonic() < deadline:
            tokens = [r.ok for r in listener.liveliness().get(pattern, timeout=2) if r.ok]
        assert tokens, f"no AdvancedPublisher token within {pattern}"
        assert all(zenoh.KeyExpr(pattern).includes(s.key_expr) for s in tokens)
        # The cache answers a query on that pattern (as an AdvancedSubscriber's history query,
        # which accepts replies on the data key) with the latched sample.
        replies = listener.get(pattern, timeout=5, accept_replies=zenoh.ReplyKeyExpr.ANY)
        cached = [r.ok for r in replies if r.ok is not None]
        assert cached and {str(s.key_expr) for s in cached} == {ros.endpoints["/tf_static"].key}
        tfm = get_typestore(Stores.ROS2_JAZZY).deserialize_cdr(
            cached[0].payload.to_bytes(), "tf2_msgs/msg/TFMessage"
        )
        assert len(tfm.transforms) == 3
