"""Export a run to MCAP with standard ROS 2 messages (Foxglove, PlotJuggler, ``ros2 bag``).

The file holds only message types of ROS 2 Humble's standard packages, CDR-encoded, each
channel with its ``ros2msg`` schema (the definition text, comments stripped, comes from the type
store that ``rosbags`` ships, ``Stores.ROS2_HUMBLE``), so ROS tools open it without any stereod
package.
The MCAP profile is ``ros2``; a metadata record ``rosbag2`` names the distro (``humble``) and
``/tf_static`` carries rosbag2's ``offered_qos_profiles`` (reliable, transient local), so
``ros2 bag play run.mcap`` republishes it latched as tf2 expects.

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

Mapping of a ``stereod.objects/1`` message (field names of :mod:`stereod.bus.messages`):

* every message and header stamp is the capture instant ``stamp_utc_ns`` (UTC, ns), split into
  ``sec`` and ``nanosec``; MCAP log_time and publish_time are the same instant;
* ``nav_msgs/msg/Odometry``, one per track state: ``header.frame_id`` = ``stereod_<rig>_optical``,
  ``child_frame_id`` = ``stereod_<rig>_track_<track_id>``; ``pose.pose.position`` =
  ``position_m`` (m); ``twist.twist.linear`` = ``velocity_mps`` (m/s), expressed in the header's
  rig frame (not in the child frame: the numbers are stereod's, unrotated); ``twist.angular`` =
  0 (not estimated). ``pose.covariance`` (6x6 row-major, m^2 and rad^2): ``position_sigma_m``
  squared on the first three diagonal entries, ``radians(heading_sigma_deg)^2`` on entry (4, 4)
  (rotation about the rig's Y axis, i.e. heading; -1, "unknown", while ``heading_valid`` is
  false or the sigma null), 0 elsewhere (roll and pitch are fixed by construction).
  ``twist.covariance``: ``velocity_sigma_mps`` squared on the first three diagonal entries and
  -1 on the angular ones (not estimated); while ``velocity_valid`` is false (or the sigma is
  null) entry 0 is -1 and the rest 0, the ROS convention for an unknown covariance, so the
  velocity's validity is explicit in the message itself. The orientation
  encodes the heading: it is the rotation about the rig frame's vertical axis (+Y, down) by
  ``heading_deg`` applied to a body frame (X forward, Y left, Z up) whose X points along the rig's
  +Z; so the child frame's +X points along the horizontal direction of motion, (sin h, 0, cos h)
  in the rig frame, and +Z points up (rig -Y). Quaternion: q_y(h) * (0.5, -0.5, 0.5, 0.5).
  While ``velocity_valid`` is false stereod publishes heading 0, so the orientation then points
  straight forward and means nothing.
* speed and heading: speed = |v| (eq. 22) = the norm of ``twist.linear``, heading = atan2(vx, vz)
  (eq. 23) in the optical rig frame, in [0, 360) deg, 0 straight away from the camera, 90
  towards +X (right). For plotting they are also on ``.../tracks/track_<id>/speed_heading``
  (``geometry_msgs/msg/Vector3Stamped``, one topic per track so PlotJuggler draws one curve per
  track), only while ``velocity_valid``: ``vector.x`` = ``speed_mps`` (m/s), ``vector.y`` =
  ``heading_deg`` (deg), ``vector.z`` = climb rate -vy (m/s, up positive), like a GNSS receiver's
  speed, track and climb. Foxglove can plot the same from Odometry with a filter, e.g.
  ``/stereod/minoru/tracks/odom{child_frame_id=="stereod_minoru_track_1"}.twist.twist.linear.z``.
* ``visualization_msgs/msg/MarkerArray``, one per message (possibly empty), in the rig frame:
  namespace ``tracks`` a sphere of diameter ``size_m`` at ``position_m`` coloured by ``state``
  (tentative yellow, confirmed green, coasting grey); ``velocity`` an arrow from the position to
  position + 1 s of velocity, while ``velocity_valid``; ``labels`` a text
  "<id> <speed> m/s <heading> deg" (the heading once ``heading_valid``; "<id> <state>" until
  ``velocity_valid``) above the sphere. Marker id =
  ``track_id``, lifetime 3 frame periods (from the messages' capture times and sequence
  numbers), so markers vanish by themselves once no message refreshes them; when a track
  disappears from the messages its markers get a DELETE.
* ``std_msgs/msg/String`` on ``/stereod/<rig>/objects``: the message's JSON exactly as published
  (the JSONL line), so nothing is lost (blobs, disparity, latency, skew, ages).

Images: each eye's frames as JPEG (default, quality 90) or PNG, ``format`` ``"jpeg"`` or
``"png"``, 8-bit grey or BGR as recorded. camera_info is published with every frame, same stamp
and frame id as the image (image_transport's pairing): K, D (``plumb_bob``, k1 k2 p1 p2 k3), R
(R1/R2), P (P1/P2, so the right eye's P[0, 3] = -fx B), width and height, from the calibration,
or from :func:`stereod.vision.calibration.canonical` for the canonical rig. A frame's stamp is its
capture instant ``t_ns`` plus the run's UTC offset (see :func:`export_run` for where the offset
comes from).
"""

from __future__ import annotations

import functools
import heapq
import itertools
import math
import re
import threading
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import IO, Any, Final, Literal, cast

import cv2
import numpy as np
from pydantic import ValidationError

from stereod.bus.messages import ObjectsMessage, ObjectState, dump
from stereod.errors import InputError, MissingInputError, StereodError
from stereod.files.output_file import AtomicOutput
from stereod.files.paths import text_path
from stereod.sources.frames import Eye, Frame
from stereod.sources.recording import (
    Manifest,
    checksum,
    damaged_frames_problem,
    read_frame_index,
    read_manifest,
)
from stereod.vision.calibration import Calibration, canonical

__all__ = [
    "BODY_TO_OPTICAL",
    "ROS_DISTRO",
    "ExportSummary",
    "McapRunWriter",
    "RosMessage",
    "RosMessages",
    "RosNames",
    "cdr_encoder",
    "export_run",
    "heading_quaternion",
    "matrix_quaternion",
    "ros2_msgdef",
]

ROS_DISTRO: Final = "humble"
"""The ROS 2 distribution whose message definitions the file's schemas are (rosbags' store)."""

BODY_TO_OPTICAL: Final = (-0.5, 0.5, -0.5, 0.5)
"""Quaternion (x, y, z, w) of ``stereod_<rig>_optical`` in ``stereod_<rig>`` (REP 103)."""

_OPTICAL_TO_BODY: Final = (0.5, -0.5, 0.5, 0.5)
_NS_PER_S: Final = 1_000_000_000
_INT32_MAX: Final = 2**31 - 1

Quaternion = tuple[float, float, float, float]

_T_IMAGE: Final = "sensor_msgs/msg/CompressedImage"
_T_INFO: Final = "sensor_msgs/msg/CameraInfo"
_T_TF: Final = "tf2_msgs/msg/TFMessage"
_T_ODOM: Final = "nav_msgs/msg/Odometry"
_T_MARKERS: Final = "visualization_msgs/msg/MarkerArray"
_T_VEC: Final = "geometry_msgs/msg/Vector3Stamped"
_T_STRING: Final = "std_msgs/msg/String"

# rosbag2's offered_qos_profiles (metadata version 8, integer enums) for a latched topic:
# keep last 1, reliable, transient local, automatic liveliness, no deadline or lifespan.
_QOS_LATCHED: Final = (
    "- history: 1\n  depth: 1\n  reliability: 1\n  durability: 1\n"
    "  deadline:\n    sec: 0\n    nsec: 0\n  lifespan:\n    sec: 0\n    nsec: 0\n"
    "  liveliness: 1\n  liveliness_lease_duration:\n    sec: 0\n    nsec: 0\n"
    "  avoid_ros_namespace_conventions: false"
)

_STATE_RGBA: Final = {
    "tentative": (1.0, 0.8, 0.0, 0.8),
    "confirmed": (0.1, 0.8, 0.2, 0.8),
    "coasting": (0.6, 0.6, 0.6, 0.6),
    "stationary": (0.1, 0.5, 0.9, 0.8),
}
_MARKER_NS: Final = ("tracks", "velocity", "labels")
_ARROW, _SPHERE, _TEXT = 0, 2, 9
_ADD, _DELETE, _DELETEALL = 0, 2, 3
MARKER_LIFETIME_PERIODS: Final = 3
"""A marker lives this many frame periods unless refreshed: the daemon re-sends every live
track's markers with each pair, so a marker outlives its track (or a daemon that died) by at
most this much instead of staying in a 3D panel for ever."""
DEFAULT_FRAME_PERIOD_S: Final = 1.0 / 15.0
"""The frame period (s) assumed until two messages show the rig's own (15 fps, the Minoru's)."""


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


@dataclass
class ExportSummary:
    """What an export wrote. Times are MCAP log times (UTC, ns); ``clock`` says where the UTC
    offset of frame stamps came from (``jsonl``, ``manifest``, ``created_utc`` (estimated, 1 s
    resolution), ``monotonic`` (unknown: stamps are the capture clock) or ``caller``)."""

    path: Path
    messages: dict[str, int]
    start_ns: int | None
    end_ns: int | None
    clock: str = "caller"
    utc_offset_ns: int | None = None
    problems: list[str] = field(default_factory=list)

    @property
    def total(self) -> int:
        """Number of messages in the file."""
        return sum(self.messages.values())

    def line(self, problems: bool = True) -> str:
        """One line for a user: file, message and topic counts, duration (s), clock, and
        what went wrong with the input unless ``problems`` is false (said apart)."""
        dur = 0.0
        if self.start_ns is not None and self.end_ns is not None:
            dur = (self.end_ns - self.start_ns) / 1e9
        return (
            f"wrote {self.path}: {self.total} messages on {len(self.messages)} topics, "
            f"{dur:.2f} s, clock from {self.clock}"
            + "".join(f"; {p}" for p in (self.problems if problems else []))
        )


def _time(stamp_ns: int) -> dict[str, int]:
    sec, nsec = divmod(int(stamp_ns), _NS_PER_S)
    if stamp_ns < 0 or sec > _INT32_MAX:
        raise InputError(
            f"stamp {stamp_ns} ns is outside ROS time (0 to 2^31 s): the UTC offset is wrong"
        )
    return {"sec": sec, "nanosec": nsec}


def _header(stamp_ns: int, frame_id: str) -> dict[str, Any]:
    return {"stamp": _time(stamp_ns), "frame_id": frame_id}


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


def _value(x: object) -> str:
    """The string of a str enum member (or of a plain string)."""
    return str(getattr(x, "value", x))


def _quat(q: Iterable[float]) -> dict[str, float]:
    x, y, z, w = (float(v) for v in q)
    return {"x": x, "y": y, "z": z, "w": w}


def _vec(v: Iterable[float]) -> dict[str, float]:
    x, y, z = (float(c) for c in v)
    return {"x": x, "y": y, "z": z}


def _rectified_baseline_m(cal: Calibration) -> float:
    p2 = cal.array("P2")
    return float(-p2[0, 3] / p2[0, 0])


@dataclass(frozen=True)
class RosMessage:
    """One ROS 2 message of a run: ``topic``, ``typename`` (``pkg/msg/Type``), ``body`` (a dict
    in the shape of the ROS 2 Humble type) and ``stamp_ns`` (its header stamp, UTC, ns)."""

    topic: str
    typename: str
    body: dict[str, Any]
    stamp_ns: int


class RosMessages:
    """The ROS 2 messages of one rig's run, mapped as the module docstring says; the MCAP writer
    and the live Foxglove server (:mod:`stereod.ros.foxglove`) both publish what this builds.

    It remembers which tracks the markers show (a track that disappears gets a DELETE), so feed
    it one run's ``objects`` messages in order, one call at a time. ``calibration`` gives
    camera_info and the cameras' frames (``vision.calibration.canonical`` for the canonical
    rig); without one, ``baseline_m`` (m) places the cameras and there is no camera_info; with
    neither (a live view that has not heard the daemon's geometry yet) there is no tf either.
    """

    def __init__(
        self,
        rig: str = "minoru",
        *,
        calibration: Calibration | None = None,
        baseline_m: float | None = None,
    ) -> None:
        self.rig = rig
        self.names = RosNames.for_rig(rig)
        self.calibration: Calibration | None = None
        self.baseline_m: float | None = None
        self._camera_info: dict[Eye, dict[str, Any]] = {}
        self._tracks: set[int] = set()
        self._arrows: set[int] = set()
        self.frame_period_s = DEFAULT_FRAME_PERIOD_S
        """The rig's frame period (s), measured between consecutive ``objects`` messages
        (capture instants over sequence numbers, so dropped pairs do not stretch it)."""
        self._last_pair: tuple[int, int] | None = None
        self.set_geometry(calibration, baseline_m)

    def set_geometry(
        self, calibration: Calibration | None, baseline_m: float | None = None
    ) -> None:
        """Use ``calibration`` (or only ``baseline_m``, m) from now on; raises
        :class:`~stereod.errors.InputError` when its rectified baseline is not positive."""
        if calibration is not None:
            b = _rectified_baseline_m(calibration)
            if not b > 0:
                raise InputError(
                    f"calibration {calibration.id}: rectified baseline {b:.4g} is not positive "
                    "(left and right swapped?): recalibrate"
                )
            self.baseline_m = b
            self._camera_info = {eye: _camera_info_body(calibration, eye) for eye in Eye}
        else:
            self.baseline_m = float(baseline_m) if baseline_m is not None else None
            self._camera_info = {}
        self.calibration = calibration

    def forget_tracks(self) -> None:
        """Start the markers afresh (a new daemon: its track ids start again)."""
        self._tracks.clear()
        self._arrows.clear()
        self._last_pair = None

    def delete_all_markers(self, stamp_ns: int) -> RosMessage:
        """A MarkerArray whose one marker is a DELETEALL (every marker of the topic goes; the
        daemon is gone), and the tracks forgotten."""
        self.forget_tracks()
        marker = self._marker(stamp_ns, "", 0, _SPHERE, _DELETEALL)
        return RosMessage(self.names.markers_topic, _T_MARKERS, {"markers": [marker]}, stamp_ns)

    def _measure_period(self, msg: ObjectsMessage) -> None:
        """Update :attr:`frame_period_s` from this message and the one before it."""
        last, self._last_pair = self._last_pair, (msg.seq, msg.t_ns)
        if last is None or msg.seq <= last[0] or msg.t_ns <= last[1]:
            return
        period = (msg.t_ns - last[1]) / (msg.seq - last[0]) * 1e-9
        if 1e-4 <= period <= 10.0:  # a pause in a replay is not the rig's frame rate
            self.frame_period_s = period

    def tf_static(self, stamp_ns: int) -> RosMessage | None:
        """``/tf_static``: body frame, rig (optical) frame, the two cameras; None while the
        geometry is unknown."""
        if self.baseline_m is None:
            return None
        names = self.names
        half = self.baseline_m / 2.0
        rot = {Eye.LEFT: np.eye(3), Eye.RIGHT: np.eye(3)}
        if self.calibration is not None:
            rot = {Eye.LEFT: self.calibration.array("R1"), Eye.RIGHT: self.calibration.array("R2")}

        def tf(parent: str, child: str, xyz: Iterable[float], q: Iterable[float]) -> dict[str, Any]:
            return {
                "header": _header(stamp_ns, parent),
                "child_frame_id": child,
                "transform": {"translation": _vec(xyz), "rotation": _quat(q)},
            }

        transforms = [
            tf(names.body_frame, names.optical_frame, (0.0, 0.0, 0.0), BODY_TO_OPTICAL),
            *(
                tf(
                    names.optical_frame,
                    names.eye_frame(eye),
                    (-half if eye is Eye.LEFT else half, 0.0, 0.0),
                    matrix_quaternion(rot[eye]),
                )
                for eye in Eye
            ),
        ]
        return RosMessage(names.tf_static_topic, _T_TF, {"transforms": transforms}, stamp_ns)

    def camera_info(self, eye: Eye, stamp_ns: int) -> RosMessage | None:
        """camera_info of ``eye`` at ``stamp_ns`` (UTC, ns); None without a calibration."""
        body = self._camera_info.get(eye)
        if body is None:
            return None
        return RosMessage(
            self.names.camera_info_topic(eye),
            _T_INFO,
            {"header": _header(stamp_ns, self.names.eye_frame(eye)), **body},
            stamp_ns,
        )

    def compressed_image(
        self, topic: str, frame_id: str, image_format: str, data: bytes, stamp_ns: int
    ) -> RosMessage:
        """A ``sensor_msgs/msg/CompressedImage`` (``image_format`` ``jpeg`` or ``png``)."""
        body = {"header": _header(stamp_ns, frame_id), "format": image_format, "data": data}
        return RosMessage(topic, _T_IMAGE, body, stamp_ns)

    def objects(self, msg: ObjectsMessage, *, raw_json: str | None = None) -> list[RosMessage]:
        """One ``stereod.objects/1`` message: Odometry per track state, speed/heading per valid
        state, the MarkerArray and the JSON (``raw_json`` if given, else re-serialised)."""
        if msg.rig != self.rig:
            raise InputError(
                f"message seq {msg.seq} is from rig {msg.rig!r}, this file is for rig "
                f"{self.rig!r}: export each rig into its own file"
            )
        stamp = msg.stamp_utc_ns
        self._measure_period(msg)
        text = raw_json.rstrip("\r\n") if raw_json is not None else dump(msg).decode()
        names = self.names
        out: list[RosMessage] = []
        for obj in msg.objects:
            out.append(RosMessage(names.odom_topic, _T_ODOM, self._odometry(obj), obj.stamp_utc_ns))
            if obj.velocity_valid:
                body = {
                    "header": _header(obj.stamp_utc_ns, names.optical_frame),
                    "vector": {
                        "x": float(obj.speed_mps),
                        "y": float(obj.heading_deg),
                        "z": -float(obj.velocity_mps[1]),
                    },
                }
                topic = names.speed_heading_topic(obj.track_id)
                out.append(RosMessage(topic, _T_VEC, body, obj.stamp_utc_ns))
        out.append(RosMessage(names.markers_topic, _T_MARKERS, self._markers(msg), stamp))
        out.append(RosMessage(names.objects_topic, _T_STRING, {"data": text}, stamp))
        return out

    def _odometry(self, obj: ObjectState) -> dict[str, Any]:
        names = self.names
        pose_cov = [0.0] * 36
        for i, s in enumerate(obj.position_sigma_m):
            pose_cov[7 * i] = float(s) ** 2
        heading_known = obj.heading_valid and obj.heading_sigma_deg is not None
        pose_cov[7 * 4] = (
            math.radians(obj.heading_sigma_deg) ** 2
            if heading_known and obj.heading_sigma_deg is not None
            else -1.0  # not estimated: ROS's "unknown"
        )
        twist_cov = [0.0] * 36
        if obj.velocity_sigma_mps is None or not obj.velocity_valid:
            twist_cov[0] = -1.0  # no valid velocity: the whole twist is "unknown"
        else:
            for i, s in enumerate(obj.velocity_sigma_mps):
                twist_cov[7 * i] = float(s) ** 2
            for i in (3, 4, 5):  # angular rates are not estimated
                twist_cov[7 * i] = -1.0
        return {
            "header": _header(obj.stamp_utc_ns, names.optical_frame),
            "child_frame_id": names.track_frame(obj.track_id),
            "pose": {
                "pose": {
                    "position": _vec(obj.position_m),
                    "orientation": _quat(heading_quaternion(obj.heading_deg)),
                },
                "covariance": pose_cov,
            },
            "twist": {
                "twist": {"linear": _vec(obj.velocity_mps), "angular": _vec((0.0, 0.0, 0.0))},
                "covariance": twist_cov,
            },
        }

    def _marker(
        self, stamp_ns: int, ns: str, track_id: int, kind: int, action: int
    ) -> dict[str, Any]:
        return {
            "header": _header(stamp_ns, self.names.optical_frame),
            "ns": ns,
            "id": int(track_id),
            "type": kind,
            "action": action,
            "pose": {"position": _vec((0.0, 0.0, 0.0)), "orientation": _quat((0, 0, 0, 1))},
            "scale": _vec((1.0, 1.0, 1.0)),
            "color": {"r": 1.0, "g": 1.0, "b": 1.0, "a": 1.0},
            "lifetime": self._lifetime(action),
            "frame_locked": False,
            "points": [],
            "colors": [],
            "texture_resource": "",
            "texture": {
                "header": _header(0, ""),
                "format": "",
                "data": b"",
            },
            "uv_coordinates": [],
            "text": "",
            "mesh_resource": "",
            "mesh_file": {"filename": "", "data": b""},
            "mesh_use_embedded_materials": False,
        }

    def _lifetime(self, action: int) -> dict[str, int]:
        """An added marker's lifetime, :data:`MARKER_LIFETIME_PERIODS` frame periods."""
        if action != _ADD:
            return {"sec": 0, "nanosec": 0}
        ns = round(MARKER_LIFETIME_PERIODS * self.frame_period_s * 1e9)
        return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}

    def _markers(self, msg: ObjectsMessage) -> dict[str, Any]:
        stamp = msg.stamp_utc_ns
        markers: list[dict[str, Any]] = []
        now = {o.track_id for o in msg.objects}
        for gone in sorted(self._tracks - now):
            kinds = zip(_MARKER_NS, (_SPHERE, _ARROW, _TEXT), strict=True)
            for ns, kind in kinds:
                if ns != "velocity" or gone in self._arrows:
                    markers.append(self._marker(stamp, ns, gone, kind, _DELETE))
            self._arrows.discard(gone)
        self._tracks = now
        for o in msg.objects:
            r, g, b, a = _STATE_RGBA.get(_value(o.state), (1.0, 1.0, 1.0, 0.8))
            color = {"r": r, "g": g, "b": b, "a": a}
            size = o.size_m if math.isfinite(o.size_m) and o.size_m > 0.01 else 0.01
            sphere = self._marker(stamp, "tracks", o.track_id, _SPHERE, _ADD)
            sphere["pose"]["position"] = _vec(o.position_m)
            sphere["scale"] = _vec((size, size, size))
            sphere["color"] = color
            markers.append(sphere)
            if o.velocity_valid:
                arrow = self._marker(stamp, "velocity", o.track_id, _ARROW, _ADD)
                tip = [p + v for p, v in zip(o.position_m, o.velocity_mps, strict=True)]
                arrow["points"] = [_vec(o.position_m), _vec(tip)]
                arrow["scale"] = _vec((0.02, 0.04, 0.06))
                arrow["color"] = color
                markers.append(arrow)
                self._arrows.add(o.track_id)
            elif o.track_id in self._arrows:
                markers.append(self._marker(stamp, "velocity", o.track_id, _ARROW, _DELETE))
                self._arrows.discard(o.track_id)
            label = self._marker(stamp, "labels", o.track_id, _TEXT, _ADD)
            x, y, z = o.position_m
            label["pose"]["position"] = _vec((x, y - size / 2.0 - 0.05, z))
            label["scale"] = _vec((0.0, 0.0, 0.05))
            label["text"] = (
                f"{o.track_id} {o.speed_mps:.2f} m/s {o.heading_deg:.0f} deg"
                if o.heading_valid
                else f"{o.track_id} {o.speed_mps:.2f} m/s"
                if o.velocity_valid
                else f"{o.track_id} {_value(o.state)}"
            )
            markers.append(label)
        return {"markers": markers}


def _camera_info_body(cal: Calibration, eye: Eye) -> dict[str, Any]:
    k, d, r, p = ("K1", "D1", "R1", "P1") if eye is Eye.LEFT else ("K2", "D2", "R2", "P2")
    w, h = cal.image_size
    return {
        "height": int(h),
        "width": int(w),
        "distortion_model": "plumb_bob",
        "d": [float(v) for v in cal.array(d).ravel()],
        "k": [float(v) for v in cal.array(k).ravel()],
        "r": [float(v) for v in cal.array(r).ravel()],
        "p": [float(v) for v in cal.array(p).ravel()],
        "binning_x": 0,
        "binning_y": 0,
        "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False},
    }


class McapRunWriter:
    """Write one run into an MCAP file, message by message, while it is in progress or offline.

    ``out`` is written by the rule of :mod:`stereod.files.output_file`: a regular file goes to a
    temporary file beside it (``.<name>.<random>.part``, beside the file a symbolic link points
    to) renamed over it by :meth:`close`, and :meth:`abort` (or an exception inside ``with``)
    removes it, leaving a previous ``out`` untouched; a device or a FIFO (``/dev/null``, a pipe
    to a reader) is written in place. Feed it in capture order: :meth:`write_frame` per eye
    frame, :meth:`write_objects` per ``stereod.objects/1`` message. ``/tf_static`` is written
    before the first message, at its stamp. Calls may come from several threads. If the process
    dies before :meth:`close`, the temporary file stays behind; ``mcap recover`` salvages it.

    ``calibration`` gives camera_info and the cameras' frames (use
    :func:`stereod.vision.calibration.canonical` for the canonical rig); without one, ``baseline_m``
    (m) places the cameras and no camera_info is written.
    """

    def __init__(
        self,
        out: Path,
        *,
        rig: str = "minoru",
        calibration: Calibration | None = None,
        baseline_m: float | None = None,
        image_format: Literal["jpeg", "png"] = "jpeg",
        jpeg_quality: int = 90,
    ) -> None:
        from mcap_ros2.writer import Writer

        if calibration is None and (baseline_m is None or not baseline_m > 0):
            raise ValueError("McapRunWriter needs a calibration or a positive baseline_m")
        if image_format not in ("jpeg", "png"):
            raise ValueError(f"image_format must be 'jpeg' or 'png', got {image_format!r}")
        self.out = Path(out)
        self.rig = rig
        self.ros = RosMessages(rig, calibration=calibration, baseline_m=baseline_m)
        self.names = self.ros.names
        self.calibration = calibration
        self.image_format = image_format
        self._encode_params = (
            [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)] if image_format == "jpeg" else []
        )
        self._lock = threading.Lock()
        self._file = AtomicOutput(self.out)
        try:
            self._ros = Writer(cast(IO[bytes], self._file))
            self._ros.add_metadata("rosbag2", {"ROS_DISTRO": ROS_DISTRO})
        except BaseException:
            self._discard()
            raise
        self._schemas: dict[str, Any] = {}
        self._counts: dict[str, int] = {}
        self._seq: dict[str, int] = {}
        self._static_done = False
        self._start: int | None = None
        self._end: int | None = None
        self._closed = False

    @property
    def baseline_m(self) -> float:
        """Distance between the cameras' frames in ``/tf_static``, m."""
        assert self.ros.baseline_m is not None
        return self.ros.baseline_m

    # -- public API ---------------------------------------------------------------------------

    @property
    def counts(self) -> dict[str, int]:
        """Messages written so far, by topic."""
        with self._lock:
            return dict(self._counts)

    def write_frame(self, frame: Frame, stamp_utc_ns: int, *, image: bool = True) -> None:
        """Write one eye frame captured at ``stamp_utc_ns`` (UTC, ns): its camera_info (when a
        calibration is known) and, with ``image``, the compressed image."""
        data = b""
        if image:
            data = self._encode(frame)
        with self._lock:
            self._check_open()
            self._static(stamp_utc_ns)
            if self.calibration is not None:
                self._check_size(frame)
                self._camera_info_locked(frame.eye, stamp_utc_ns)
            if image:
                self._write(
                    self.ros.compressed_image(
                        self.names.image_topic(frame.eye),
                        self.names.eye_frame(frame.eye),
                        self.image_format,
                        data,
                        stamp_utc_ns,
                    )
                )

    def write_camera_info(self, eye: Eye, stamp_utc_ns: int) -> None:
        """Write one camera_info of ``eye`` at ``stamp_utc_ns`` (UTC, ns) without an image."""
        if self.calibration is None:
            raise ValueError("camera_info needs a calibration")
        with self._lock:
            self._check_open()
            self._static(stamp_utc_ns)
            self._camera_info_locked(eye, stamp_utc_ns)

    def write_objects(self, msg: ObjectsMessage, *, raw_json: str | None = None) -> None:
        """Write one ``stereod.objects/1`` message: Odometry per track state, speed/heading per
        valid state, the MarkerArray and the JSON (``raw_json`` if given, else re-serialised)."""
        with self._lock:
            self._check_open()
            messages = self.ros.objects(msg, raw_json=raw_json)
            self._static(msg.stamp_utc_ns)
            for m in messages:
                self._write(m)

    def close(self) -> ExportSummary:
        """Finish the MCAP (summary, indexes), sync it and rename it over ``out``."""
        with self._lock:
            self._check_open()
            self._closed = True
            try:
                self._ros.finish()
                self._file.commit()
            except BaseException:
                self._discard()
                raise
            return ExportSummary(
                path=self.out,
                messages=dict(sorted(self._counts.items())),
                start_ns=self._start,
                end_ns=self._end,
            )

    def abort(self) -> None:
        """Stop writing and remove the temporary file; ``out`` is left as it was. Idempotent."""
        with self._lock:
            self._closed = True
            self._discard()

    def __enter__(self) -> McapRunWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is not None:
            self.abort()
        elif not self._closed:
            self.close()

    # -- internals ----------------------------------------------------------------------------

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError(f"{self.out}: MCAP writer already closed")

    def _check_size(self, frame: Frame) -> None:
        assert self.calibration is not None
        w, h = self.calibration.image_size
        if frame.image.shape[:2] != (h, w):
            raise InputError(
                f"{frame.eye.value} frame {frame.seq} is {frame.image.shape[1]}x"
                f"{frame.image.shape[0]}, the calibration is for {w}x{h}: use the calibration "
                "made for this camera mode"
            )

    def _discard(self) -> None:
        self._file.discard()

    def _schema(self, typename: str) -> Any:
        schema = self._schemas.get(typename)
        if schema is None:
            schema = self._ros.register_msgdef(typename, _msgdef(typename))
            self._schemas[typename] = schema
        return schema

    def _register_latched(self, topic: str, typename: str) -> None:
        # mcap-ros2-support registers channels without metadata; rosbag2 needs the QoS profile
        # of a latched topic there, so register the channel ourselves when its internals allow.
        schema = self._schema(typename)
        inner = getattr(self._ros, "_writer", None)
        ids = getattr(self._ros, "_channel_ids", None)
        if inner is None or not isinstance(ids, dict) or topic in ids:
            return
        ids[topic] = inner.register_channel(
            topic=topic,
            message_encoding="cdr",
            schema_id=schema.id,
            metadata={"offered_qos_profiles": _QOS_LATCHED},
        )

    def _put(self, topic: str, typename: str, message: dict[str, Any], stamp_ns: int) -> None:
        if stamp_ns < 0:
            raise InputError(
                f"{topic}: stamp {stamp_ns} ns is before 1970: the UTC offset is wrong"
            )
        seq = self._seq.get(topic, 0)
        self._ros.write_message(
            topic,
            self._schema(typename),
            message,
            log_time=stamp_ns,
            publish_time=stamp_ns,
            sequence=seq,
        )
        self._seq[topic] = seq + 1
        self._counts[topic] = self._counts.get(topic, 0) + 1
        self._start = stamp_ns if self._start is None else min(self._start, stamp_ns)
        self._end = stamp_ns if self._end is None else max(self._end, stamp_ns)

    def _write(self, m: RosMessage) -> None:
        self._put(m.topic, m.typename, m.body, m.stamp_ns)

    def _static(self, stamp_ns: int) -> None:
        if self._static_done:
            return
        self._static_done = True
        static = self.ros.tf_static(stamp_ns)
        assert static is not None  # the writer always has a calibration or a baseline
        self._register_latched(static.topic, static.typename)
        self._write(static)

    def _camera_info_locked(self, eye: Eye, stamp_ns: int) -> None:
        info = self.ros.camera_info(eye, stamp_ns)
        if info is not None:
            self._write(info)

    def _encode(self, frame: Frame) -> bytes:
        ext = ".jpg" if self.image_format == "jpeg" else ".png"
        img = frame.image
        if img.dtype != np.uint8 or img.ndim not in (2, 3):
            raise InputError(
                f"{frame.eye.value} frame {frame.seq}: expected 8-bit grey or BGR pixels, got "
                f"{img.dtype} of shape {img.shape}"
            )
        ok, buf = cv2.imencode(ext, img, self._encode_params)
        if not ok:
            raise InputError(f"{frame.eye.value} frame {frame.seq}: cannot encode as {ext}")
        return buf.tobytes()


# -- offline export -------------------------------------------------------------------------


MAX_TRACK_ID = 2**31 - 1
"""Largest track id exported: a marker's id is an int32 (a daemon numbers its tracks from 1
and would need 68 years at one new track a second to reach it)."""


def _jsonl_messages(path: Path) -> Iterator[tuple[int, ObjectsMessage, str]]:
    """(line number, message, line) of each non-blank line, validated; errors name the line."""
    try:
        fh = path.open(encoding="utf-8", newline="")
    except FileNotFoundError as exc:
        raise MissingInputError(
            f"{path}: no such JSONL file; write one with `stereod replay RECORDING --jsonl {path}`"
        ) from exc
    except OSError as exc:
        raise MissingInputError(f"{path}: cannot read JSONL file: {exc.strerror}") from exc
    n = 0
    with fh:
        try:
            for n, raw in enumerate(fh, start=1):
                line = raw.rstrip("\r\n")
                if not line.strip():
                    continue
                try:
                    msg = ObjectsMessage.model_validate_json(line)
                except ValidationError as exc:
                    e = exc.errors(include_url=False)[0]
                    loc = ".".join(str(p) for p in e["loc"]) or "(line)"
                    raise InputError(
                        f"{path} line {n}: not a stereod.objects/1 message (field {loc}: "
                        f"{e['msg']}); regenerate the file with `stereod replay --jsonl`"
                    ) from exc
                for obj in msg.objects:
                    if not 0 <= obj.track_id <= MAX_TRACK_ID:
                        raise InputError(
                            f"{path} line {n}: track_id {obj.track_id} is outside "
                            f"0..{MAX_TRACK_ID}, the ids a ROS marker (int32) can carry; "
                            "regenerate the file with `stereod replay --jsonl`"
                        )
                yield n, msg, line
        except UnicodeDecodeError as exc:
            raise InputError(
                f"{path} line {n + 1}: not UTF-8 text; regenerate the file with "
                "`stereod replay --jsonl`"
            ) from exc
        except OSError as exc:
            raise InputError(f"{path}: cannot read JSONL file: {exc.strerror}") from exc


@dataclass
class _JsonlScan:
    """What a first pass over the JSONL found (messages are not kept: a run can be long)."""

    count: int = 0
    rigs: set[str] = field(default_factory=set)
    kinds: set[tuple[str, str | None]] = field(default_factory=set)
    offset_ns: int | None = None


def _scan_jsonl(path: Path, bounds: tuple[int, int] | None, recording: Path | None) -> _JsonlScan:
    scan = _JsonlScan()
    for n, msg, _ in _jsonl_messages(path):
        scan.count += 1
        scan.rigs.add(msg.rig)
        scan.kinds.add((_value(msg.geometry), msg.calibration_id))
        if scan.offset_ns is None:
            scan.offset_ns = msg.stamp_utc_ns - msg.t_ns
        if bounds is not None and not bounds[0] <= msg.t_ns <= bounds[1]:
            raise InputError(
                f"{path} line {n}: t_ns {msg.t_ns} is outside the recording {recording} "
                f"({bounds[0]}..{bounds[1]} ns): the JSONL is from another run; pass the "
                "matching pair"
            )
    return scan


@dataclass
class _Eye:
    eye: Eye
    video: Path
    t_ns: np.ndarray
    seq: np.ndarray
    crc: np.ndarray | None
    """Each frame's CRC-32 as recorded (lossless recordings), or None."""
    index: Path
    """The timestamp CSV the times and CRC-32s were read from."""


def _read_recording(directory: Path) -> tuple[Manifest, dict[Eye, _Eye]]:
    man = read_manifest(directory)
    eyes = {}
    for eye, files in ((Eye.LEFT, man.left), (Eye.RIGHT, man.right)):
        t, seq, crc = read_frame_index(directory / files.timestamps)
        if len(t) != files.frames:
            raise InputError(
                f"{directory / files.timestamps}: {len(t)} timestamps, the manifest says "
                f"{files.frames} frames; the recording is incomplete: record it again"
            )
        video = directory / files.video
        if not video.is_file():
            raise MissingInputError(f"{video}: no such video file; the recording is incomplete")
        eyes[eye] = _Eye(eye, video, t, seq, crc, directory / files.timestamps)
    return man, eyes


def _decode(rec: _Eye, gray: bool, problems: list[str]) -> Iterator[Frame]:
    cap = cv2.VideoCapture(text_path(rec.video, "video"), cv2.CAP_FFMPEG)
    if not cap.isOpened():
        raise InputError(f"{rec.video}: cannot open as a video (corrupt or unsupported codec)")
    if gray:
        cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
    damaged: list[int] = []
    try:
        for i in itertools.count():
            ok, img = cap.read()
            if not ok or img is None:
                if i < len(rec.t_ns):
                    problems.append(
                        f"{rec.video}: truncated, {i} of {len(rec.t_ns)} frames decoded; "
                        "exported those"
                    )
                return
            if i >= len(rec.t_ns):
                raise InputError(
                    f"{rec.video}: has more frames than its {len(rec.t_ns)} timestamps; the "
                    "recording is inconsistent: record it again"
                )
            if gray and img.ndim == 3:
                img = np.ascontiguousarray(img[..., 0])
            if rec.crc is not None and checksum(img) != rec.crc[i]:
                damaged.append(i)
                continue
            yield Frame(rec.eye, img, int(rec.t_ns[i]), int(rec.seq[i]))
    finally:
        cap.release()
        if damaged:
            problems.append(damaged_frames_problem(rec.video, rec.index, damaged, "not exported"))


def _frame_events(
    rec: _Eye, order: int, offset: int, images: bool, gray: bool, problems: list[str]
) -> Iterator[tuple[int, int, Frame | Eye]]:
    """(stamp, order, frame) per decoded frame, or (stamp, order, eye) per timestamp row."""
    if images:
        for f in _decode(rec, gray, problems):
            yield f.t_ns + offset, order, f
    else:
        for t in rec.t_ns:
            yield int(t) + offset, order, rec.eye


def _created_utc_ns(man: Manifest) -> int | None:
    import datetime

    try:
        dt = datetime.datetime.strptime(man.created_utc, "%Y-%m-%dT%H:%M:%SZ")
    except ValueError:
        return None
    return int(dt.replace(tzinfo=datetime.timezone.utc).timestamp()) * _NS_PER_S


def _choose_geometry(
    kinds: set[tuple[str, str | None]],
    jsonl: Path | None,
    calibration: Calibration | None,
    man: Manifest | None,
    recording: Path | None,
    baseline_m: float,
    hfov_deg: float,
) -> Calibration | None:
    recorded: Calibration | None = None
    if man is not None and man.calibration is not None:
        try:
            recorded = Calibration.model_validate(man.calibration)
        except ValidationError as exc:
            raise InputError(
                f"{recording}: the manifest's calibration is invalid; pass --calibration"
            ) from exc
        recorded = recorded.model_copy(update={"id": recorded.content_id()})
    if len(kinds) > 1:
        raise InputError(
            f"{jsonl}: the messages mix geometries {sorted(kinds, key=str)}; export one run"
        )
    used = next(iter(kinds)) if kinds else None
    cal: Calibration | None
    if used is not None and used[0] == "calibrated":
        want = used[1]
        if calibration is not None:
            if calibration.id != want:
                raise InputError(
                    f"{jsonl}: the run used calibration {want}, the one given is "
                    f"{calibration.id}: pass the calibration file the run used"
                )
            cal = calibration
        elif recorded is not None and recorded.id == want:
            cal = recorded
        else:
            raise MissingInputError(
                f"{jsonl}: the run used calibration {want}: pass that calibration file"
            )
    elif used is not None:
        if calibration is not None:
            raise InputError(
                f"{jsonl}: the run used the canonical rig but a calibration was given: drop the "
                "calibration, or replay the recording with it first"
            )
        cal = None
    else:
        cal = calibration if calibration is not None else recorded
    if cal is None and man is not None:
        try:
            cal = canonical(baseline_m, hfov_deg, man.width, man.height)
        except StereodError as exc:
            raise InputError(f"rig geometry: {exc}") from exc
    if cal is not None and man is not None and tuple(cal.image_size) != (man.width, man.height):
        w, h = cal.image_size
        raise InputError(
            f"{recording}: frames are {man.width}x{man.height}, the calibration is for {w}x{h}: "
            "pass the calibration made for this camera mode"
        )
    return cal


def export_run(
    out: Path,
    *,
    jsonl: Path | None,
    recording: Path | None,
    calibration: Calibration | None = None,
    baseline_m: float = 0.060,
    hfov_deg: float = 60.0,
    include_images: bool = True,
    rig: str | None = None,
    image_format: Literal["jpeg", "png"] = "jpeg",
    jpeg_quality: int = 90,
) -> ExportSummary:
    """Export a finished run to the MCAP file ``out`` (atomically: see :class:`McapRunWriter`).

    ``jsonl``: the ``stereod.objects/1`` messages (``stereod replay --jsonl``), one per line.
    ``recording``: the recording directory (images and per-frame camera_info; with
    ``include_images=False`` only camera_info, from the timestamp files, nothing decoded). At
    least one is needed. ``calibration``: the calibration the run used; when the JSONL says
    ``calibrated`` it must be that one (by id; the recording's own calibration is used when it
    matches). Otherwise the canonical rig of ``baseline_m`` (m) and ``hfov_deg`` (deg) is used,
    which must be the values the run used. ``rig``: default the JSONL's ``rig``, else ``minoru``.

    Stamps: a message's stamp is its ``stamp_utc_ns``. A frame's is its ``t_ns`` plus the UTC
    offset, taken from, in order: the JSONL (``stamp_utc_ns - t_ns`` of its first message, so
    frames and tracks line up exactly); the manifest's ``utc_offset_ns`` (live recordings); the
    manifest's ``created_utc`` minus the first frame's ``t_ns`` (an estimate to 1 s, e.g. for
    synthetic recordings); else 0, stamps then being the capture clock (``clock`` in the
    summary says which). Messages are written in stamp order.

    Raises :class:`~stereod.errors.MissingInputError`, :class:`~stereod.errors.InputError` or
    :class:`~stereod.errors.OutputError`; then ``out`` is as it was and no temporary is left.
    """
    if jsonl is None and recording is None:
        raise InputError(
            f"{out}: nothing to export: give the run's JSONL (stereod replay --jsonl) and/or "
            "its recording directory"
        )
    if not baseline_m > 0 or not 0 < hfov_deg < 180:
        raise InputError(
            f"rig geometry: baseline {baseline_m} m, field of view {hfov_deg} deg: need a baseline "
            "> 0 and a field of view in (0, 180), the values the run used"
        )
    man: Manifest | None = None
    eyes: dict[Eye, _Eye] = {}
    if recording is not None:
        man, eyes = _read_recording(recording)
    lo = min((int(e.t_ns[0]) for e in eyes.values() if len(e.t_ns)), default=None)
    hi = max((int(e.t_ns[-1]) for e in eyes.values() if len(e.t_ns)), default=None)
    bounds = (lo, hi) if lo is not None and hi is not None else None
    scan = _scan_jsonl(jsonl, bounds, recording) if jsonl is not None else _JsonlScan()
    if len(scan.rigs) > 1:
        raise InputError(f"{jsonl}: messages from several rigs {sorted(scan.rigs)}; export one rig")
    if rig is None:
        rig = next(iter(scan.rigs)) if scan.rigs else "minoru"
    elif scan.rigs and rig not in scan.rigs:
        raise InputError(
            f"{jsonl}: the messages are from rig {next(iter(scan.rigs))!r}, not {rig!r}"
        )
    cal = _choose_geometry(scan.kinds, jsonl, calibration, man, recording, baseline_m, hfov_deg)

    clock, offset = "monotonic", 0
    if scan.offset_ns is not None:
        clock, offset = "jsonl", scan.offset_ns
    elif man is not None and man.utc_offset_ns is not None:
        clock, offset = "manifest", man.utc_offset_ns
    elif lo is not None and man is not None and (created := _created_utc_ns(man)) is not None:
        clock, offset = "created_utc", created - lo

    problems: list[str] = []
    gray = man is None or not man.color
    streams: list[Iterator[tuple[int, int, Any]]] = [
        _frame_events(rec, order, offset, include_images, gray, problems)
        for order, rec in enumerate(eyes.values())
    ]
    if jsonl is not None:
        streams.append((m.stamp_utc_ns, 2, (m, line)) for _, m, line in _jsonl_messages(jsonl))

    writer = McapRunWriter(
        out,
        rig=rig,
        calibration=cal,
        baseline_m=baseline_m,
        image_format=image_format,
        jpeg_quality=jpeg_quality,
    )
    with writer:
        for stamp, _, item in heapq.merge(*streams, key=lambda e: e[0]):
            if isinstance(item, Frame):
                writer.write_frame(item, stamp)
            elif isinstance(item, Eye):
                if cal is not None:
                    writer.write_camera_info(item, stamp)
            else:
                msg, line = item
                writer.write_objects(msg, raw_json=line)
        summary = writer.close()
    summary.clock = clock
    summary.utc_offset_ns = offset
    summary.problems = problems
    return summary
