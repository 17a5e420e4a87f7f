"""ROS names of a rig's run: topics, frame ids, message types and their schemas, time
stamps and quaternions.

Topics and frames (``<rig>`` is the rig name, e.g. ``minoru``; characters a ROS name does not
allow become ``_``):

* ``/stereod/<rig>/left/image/compressed``, ``/stereod/<rig>/right/image/compressed``:
  ``sensor_msgs/msg/CompressedImage``, one per frame of that eye;
* ``/stereod/<rig>/left/camera_info``, ``/stereod/<rig>/right/camera_info``:
  ``sensor_msgs/msg/CameraInfo``, one per frame of that eye;
* ``/tf_static``: ``tf2_msgs/msg/TFMessage``, one, before everything else;
* ``/stereod/<rig>/tracks/odom``: ``nav_msgs/msg/Odometry``, one per track state;
* ``/stereod/<rig>/tracks/markers``: ``visualization_msgs/msg/MarkerArray``, one per message;
* ``/stereod/<rig>/tracks/track_<id>/speed_heading``: ``geometry_msgs/msg/Vector3Stamped``, one
  per track state with ``velocity_valid`` true;
* ``/stereod/<rig>/objects``: ``std_msgs/msg/String``, one per message.

A "message" is one ``stereod.objects/1`` message (one JSONL line, one stereo pair); a "track
state" is one entry of its ``objects`` list.

Frames (REP 103/105). stereod's rig frame is already an optical-style frame: X right, Y down,
Z forward, origin at the midpoint of the baseline. ROS body frames are X forward, Y left, Z up.
``/tf_static`` publishes this tree:

* ``stereod_<rig>`` (body: X forward, Y left, Z up), the frame to attach to a robot;
* ``stereod_<rig>_optical``: the stereod rig frame, child of the body frame with zero translation
  and the standard optical rotation, quaternion (x, y, z, w) = (-0.5, 0.5, -0.5, 0.5) from body
  to optical. Its matrix (optical axes as columns in body coordinates) is
  ``[[0, 0, 1], [-1, 0, 0], [0, -1, 0]]``: rig +Z (forward) is body +X, rig +X (right) is body
  -Y, rig +Y (down) is body -Z; a rig point p is R p in the body frame;
* ``stereod_<rig>_left_optical`` and ``stereod_<rig>_right_optical``: the two cameras, children of
  the rig frame at x = -B/2 and x = +B/2 (B = the rectified baseline, -P2[0,3] / P2[0,0]),
  rotated by R1 and R2 of the calibration (the rectification: a point in camera coordinates is
  R1 p in the rectified frame, which has the rig frame's axes); identity for the canonical rig.
  Images and camera_info carry these frame ids.
"""

from __future__ import annotations

import functools
import math
import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, Final

import numpy as np

from stereod.errors import InputError
from stereod.files.bounds import ROS_TIME_NS_MAX
from stereod.sources.frames import Eye
from stereod.vision.calibration import Calibration

ROS_DISTRO: Final = "humble"
"""The ROS 2 distribution whose message definitions the file's schemas are (rosbags' store)."""

BODY_TO_OPTICAL: Final = (-0.5, 0.5, -0.5, 0.5)
"""Quaternion (x, y, z, w) of ``stereod_<rig>_optical`` in ``stereod_<rig>`` (REP 103)."""

_OPTICAL_TO_BODY: Final = (0.5, -0.5, 0.5, 0.5)
NS_PER_S: Final = 1_000_000_000

Quaternion = tuple[float, float, float, float]

T_IMAGE: Final = "sensor_msgs/msg/CompressedImage"
T_INFO: Final = "sensor_msgs/msg/CameraInfo"
T_TF: Final = "tf2_msgs/msg/TFMessage"
T_ODOM: Final = "nav_msgs/msg/Odometry"
T_MARKERS: Final = "visualization_msgs/msg/MarkerArray"
T_VEC: Final = "geometry_msgs/msg/Vector3Stamped"
T_STRING: Final = "std_msgs/msg/String"

# rosbag2's offered_qos_profiles (metadata version 8, integer enums) for a latched topic:
# keep last 1, reliable, transient local, automatic liveliness, no deadline or lifespan.
QOS_LATCHED: Final = (
    "- history: 1\n  depth: 1\n  reliability: 1\n  durability: 1\n"
    "  deadline:\n    sec: 0\n    nsec: 0\n  lifespan:\n    sec: 0\n    nsec: 0\n"
    "  liveliness: 1\n  liveliness_lease_duration:\n    sec: 0\n    nsec: 0\n"
    "  avoid_ros_namespace_conventions: false"
)


@functools.cache
def _msgdef(typename: str) -> str:
    """The ros2msg schema text of a standard type, from rosbags' ROS 2 Humble store."""
    from rosbags.typesys import Stores, get_typestore

    text, _ = get_typestore(Stores.ROS2_HUMBLE).generate_msgdef(typename, ros_version=2)
    return text


def ros2_msgdef(typename: str) -> str:
    """The ``ros2msg`` schema text of a standard type (``pkg/msg/Type``), as the MCAP file and
    the live Foxglove server advertise it: ROS 2 Humble's definition, from rosbags' store."""
    return _msgdef(typename)


@functools.cache
def cdr_encoder(typename: str) -> Callable[[dict[str, Any]], bytes]:
    """A function that CDR-encodes a message body (a dict in the shape of the Humble type) of
    ``typename``: the encoder the MCAP writer uses (mcap-ros2-support's), for the live server."""
    from mcap_ros2._dynamic import serialize_dynamic

    encoders = serialize_dynamic(typename, _msgdef(typename))
    encode = encoders[typename]

    def run(body: dict[str, Any]) -> bytes:
        return bytes(encode(body))

    return run


def _ros_name(rig: str) -> str:
    name = re.sub(r"[^A-Za-z0-9_]", "_", rig) or "rig"
    return f"rig_{name}" if name[0].isdigit() else name


@dataclass(frozen=True)
class RosNames:
    """Topic names and frame ids of one rig (``rig`` sanitised to ``[A-Za-z0-9_]``)."""

    rig: str

    @classmethod
    def for_rig(cls, rig: str) -> RosNames:
        """Names for a stereod rig name; invalid characters become ``_``."""
        return cls(_ros_name(rig))

    @property
    def body_frame(self) -> str:
        """``stereod_<rig>``: X forward, Y left, Z up."""
        return f"stereod_{self.rig}"

    @property
    def optical_frame(self) -> str:
        """``stereod_<rig>_optical``: stereod's rig frame (X right, Y down, Z forward)."""
        return f"stereod_{self.rig}_optical"

    def eye_frame(self, eye: Eye) -> str:
        """``stereod_<rig>_left_optical`` / ``..._right_optical``: one camera's optical frame."""
        return f"stereod_{self.rig}_{eye.value}_optical"

    def track_frame(self, track_id: int) -> str:
        """``stereod_<rig>_track_<id>``: Odometry's child frame of one track."""
        return f"stereod_{self.rig}_track_{track_id}"

    def image_topic(self, eye: Eye) -> str:
        """``/stereod/<rig>/<eye>/image/compressed``."""
        return f"/stereod/{self.rig}/{eye.value}/image/compressed"

    def camera_info_topic(self, eye: Eye) -> str:
        """``/stereod/<rig>/<eye>/camera_info``."""
        return f"/stereod/{self.rig}/{eye.value}/camera_info"

    @property
    def overlay_topic(self) -> str:
        """``/stereod/<rig>/overlay/image/compressed``: the annotated overlay (live only)."""
        return f"/stereod/{self.rig}/overlay/image/compressed"

    @property
    def odom_topic(self) -> str:
        """``/stereod/<rig>/tracks/odom``."""
        return f"/stereod/{self.rig}/tracks/odom"

    @property
    def markers_topic(self) -> str:
        """``/stereod/<rig>/tracks/markers``."""
        return f"/stereod/{self.rig}/tracks/markers"

    def speed_heading_topic(self, track_id: int) -> str:
        """``/stereod/<rig>/tracks/track_<id>/speed_heading``."""
        return f"/stereod/{self.rig}/tracks/track_{track_id}/speed_heading"

    @property
    def objects_topic(self) -> str:
        """``/stereod/<rig>/objects``: the JSON messages."""
        return f"/stereod/{self.rig}/objects"

    @property
    def tf_static_topic(self) -> str:
        """``/tf_static``."""
        return "/tf_static"


def ros_time(stamp_ns: int) -> dict[str, int]:
    sec, nsec = divmod(int(stamp_ns), NS_PER_S)
    if not 0 <= stamp_ns <= ROS_TIME_NS_MAX:
        raise InputError(
            f"stamp {stamp_ns} ns is outside ROS time (0 to 2^31 s): the UTC offset is wrong"
        )
    return {"sec": sec, "nanosec": nsec}


def header(stamp_ns: int, frame_id: str) -> dict[str, Any]:
    return {"stamp": ros_time(stamp_ns), "frame_id": frame_id}


def _qmul(a: Quaternion, b: Quaternion) -> Quaternion:
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def heading_quaternion(heading_deg: float) -> Quaternion:
    """Orientation (x, y, z, w) in the optical rig frame of a body frame (X forward, Z up)
    turned to ``heading_deg`` (deg, eq. 23): its +X is (sin h, 0, cos h), its +Z is -Y."""
    half = math.radians(heading_deg) / 2.0
    return _qmul((0.0, math.sin(half), 0.0, math.cos(half)), _OPTICAL_TO_BODY)


def matrix_quaternion(r: np.ndarray) -> Quaternion:
    """Quaternion (x, y, z, w), w >= 0, of a 3x3 rotation matrix (re-orthonormalised first)."""
    u, _, vt = np.linalg.svd(np.asarray(r, dtype=np.float64).reshape(3, 3))
    m = u @ vt
    if np.linalg.det(m) < 0:
        raise InputError("calibration: R1 or R2 is a reflection, not a rotation: recalibrate")
    tr = float(np.trace(m))
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2.0
        q = ((m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4)
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2.0
        q = (s / 4, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s)
    elif m[1, 1] > m[2, 2]:
        s = math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2.0
        q = ((m[0, 1] + m[1, 0]) / s, s / 4, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s)
    else:
        s = math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2.0
        q = ((m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, s / 4, (m[1, 0] - m[0, 1]) / s)
    a = np.asarray(q, dtype=np.float64)
    a /= np.linalg.norm(a)
    if a[3] < 0:
        a = -a
    return (float(a[0]), float(a[1]), float(a[2]), float(a[3]))


def value_text(x: object) -> str:
    """The string of a str enum member (or of a plain string)."""
    return str(getattr(x, "value", x))


def quat(q: Iterable[float]) -> dict[str, float]:
    x, y, z, w = (float(v) for v in q)
    return {"x": x, "y": y, "z": z, "w": w}


def vec(v: Iterable[float]) -> dict[str, float]:
    x, y, z = (float(c) for c in v)
    return {"x": x, "y": y, "z": z}


def rectified_baseline_m(cal: Calibration) -> float:
    p2 = cal.array("P2")
    return float(-p2[0, 3] / p2[0, 0])
