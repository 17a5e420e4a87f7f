"""A ``stereod.objects/1`` message as standard ROS 2 messages (Humble types), for the MCAP
file and the live Foxglove server.

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
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, Final

import numpy as np

from stereod.bus.messages import ObjectsMessage, ObjectState, dump
from stereod.errors import InputError
from stereod.ros.names import (
    BODY_TO_OPTICAL,
    T_IMAGE,
    T_INFO,
    T_MARKERS,
    T_ODOM,
    T_STRING,
    T_TF,
    T_VEC,
    RosNames,
    header,
    heading_quaternion,
    matrix_quaternion,
    quat,
    rectified_baseline_m,
    value_text,
    vec,
)
from stereod.sources.frames import Eye
from stereod.vision.calibration import Calibration

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
            b = rectified_baseline_m(calibration)
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
        return RosMessage(self.names.markers_topic, T_MARKERS, {"markers": [marker]}, stamp_ns)

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
                "header": header(stamp_ns, parent),
                "child_frame_id": child,
                "transform": {"translation": vec(xyz), "rotation": quat(q)},
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
        return RosMessage(names.tf_static_topic, T_TF, {"transforms": transforms}, stamp_ns)

    def camera_info(self, eye: Eye, stamp_ns: int) -> RosMessage | None:
        """camera_info of ``eye`` at ``stamp_ns`` (UTC, ns); None without a calibration."""
        body = self._camera_info.get(eye)
        if body is None:
            return None
        return RosMessage(
            self.names.camera_info_topic(eye),
            T_INFO,
            {"header": header(stamp_ns, self.names.eye_frame(eye)), **body},
            stamp_ns,
        )

    def compressed_image(
        self, topic: str, frame_id: str, image_format: str, data: bytes, stamp_ns: int
    ) -> RosMessage:
        """A ``sensor_msgs/msg/CompressedImage`` (``image_format`` ``jpeg`` or ``png``)."""
        body = {"header": header(stamp_ns, frame_id), "format": image_format, "data": data}
        return RosMessage(topic, T_IMAGE, body, stamp_ns)

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
            out.append(RosMessage(names.odom_topic, T_ODOM, self._odometry(obj), obj.stamp_utc_ns))
            if obj.velocity_valid:
                body = {
                    "header": header(obj.stamp_utc_ns, names.optical_frame),
                    "vector": {
                        "x": float(obj.speed_mps),
                        "y": float(obj.heading_deg),
                        "z": -float(obj.velocity_mps[1]),
                    },
                }
                topic = names.speed_heading_topic(obj.track_id)
                out.append(RosMessage(topic, T_VEC, body, obj.stamp_utc_ns))
        out.append(RosMessage(names.markers_topic, T_MARKERS, self._markers(msg), stamp))
        out.append(RosMessage(names.objects_topic, T_STRING, {"data": text}, stamp))
        return out

    def _odometry(self, obj: ObjectState) -> dict[str, Any]:
        names = self.names
        pose_cov = [0.0] * 36
        for i, s in enumerate(obj.position_sigma_m):
            pose_cov[7 * i] = _square(s)
        heading_known = obj.heading_valid and obj.heading_sigma_deg is not None
        pose_cov[7 * 4] = (
            _square(math.radians(obj.heading_sigma_deg))
            if heading_known and obj.heading_sigma_deg is not None
            else -1.0  # not estimated: ROS's "unknown"
        )
        twist_cov = [0.0] * 36
        if obj.velocity_sigma_mps is None or not obj.velocity_valid:
            twist_cov[0] = -1.0  # no valid velocity: the whole twist is "unknown"
        else:
            for i, s in enumerate(obj.velocity_sigma_mps):
                twist_cov[7 * i] = _square(s)
            for i in (3, 4, 5):  # angular rates are not estimated
                twist_cov[7 * i] = -1.0
        return {
            "header": header(obj.stamp_utc_ns, names.optical_frame),
            "child_frame_id": names.track_frame(obj.track_id),
            "pose": {
                "pose": {
                    "position": vec(obj.position_m),
                    "orientation": quat(heading_quaternion(obj.heading_deg)),
                },
                "covariance": pose_cov,
            },
            "twist": {
                "twist": {"linear": vec(obj.velocity_mps), "angular": vec((0.0, 0.0, 0.0))},
                "covariance": twist_cov,
            },
        }

    def _marker(
        self, stamp_ns: int, ns: str, track_id: int, kind: int, action: int
    ) -> dict[str, Any]:
        return {
            "header": header(stamp_ns, self.names.optical_frame),
            "ns": ns,
            "id": int(track_id),
            "type": kind,
            "action": action,
            "pose": {"position": vec((0.0, 0.0, 0.0)), "orientation": quat((0, 0, 0, 1))},
            "scale": vec((1.0, 1.0, 1.0)),
            "color": {"r": 1.0, "g": 1.0, "b": 1.0, "a": 1.0},
            "lifetime": self._lifetime(action),
            "frame_locked": False,
            "points": [],
            "colors": [],
            "texture_resource": "",
            "texture": {
                "header": header(0, ""),
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
            r, g, b, a = _STATE_RGBA.get(value_text(o.state), (1.0, 1.0, 1.0, 0.8))
            color = {"r": r, "g": g, "b": b, "a": a}
            size = o.size_m if math.isfinite(o.size_m) and o.size_m > 0.01 else 0.01
            sphere = self._marker(stamp, "tracks", o.track_id, _SPHERE, _ADD)
            sphere["pose"]["position"] = vec(o.position_m)
            sphere["scale"] = vec((size, size, size))
            sphere["color"] = color
            markers.append(sphere)
            if o.velocity_valid:
                arrow = self._marker(stamp, "velocity", o.track_id, _ARROW, _ADD)
                tip = [p + v for p, v in zip(o.position_m, o.velocity_mps, strict=True)]
                arrow["points"] = [vec(o.position_m), vec(tip)]
                arrow["scale"] = vec((0.02, 0.04, 0.06))
                arrow["color"] = color
                markers.append(arrow)
                self._arrows.add(o.track_id)
            elif o.track_id in self._arrows:
                markers.append(self._marker(stamp, "velocity", o.track_id, _ARROW, _DELETE))
                self._arrows.discard(o.track_id)
            label = self._marker(stamp, "labels", o.track_id, _TEXT, _ADD)
            x, y, z = o.position_m
            label["pose"]["position"] = vec((x, y - size / 2.0 - 0.05, z))
            label["scale"] = vec((0.0, 0.0, 0.05))
            label["text"] = (
                f"{o.track_id} {o.speed_mps:.2f} m/s {o.heading_deg:.0f} deg"
                if o.heading_valid
                else f"{o.track_id} {o.speed_mps:.2f} m/s"
                if o.velocity_valid
                else f"{o.track_id} {value_text(o.state)}"
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


def _square(sigma: float) -> float:
    """A sigma as its variance: infinite for one whose square passes the float range (a
    hand-edited run's 1e300), where ``** 2`` raised OverflowError."""
    s = float(sigma)
    return s * s
