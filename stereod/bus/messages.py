"""Wire messages published on Zenoh (design sec. 4), defined once as pydantic models, and the
translation of the pipeline's results into them.

Payloads are JSON with encoding ``application/json;stereod.<message>/<version>``; every message
has a ``schema`` field with that ``stereod.<message>/<version>`` string. Within a version fields
are only ever added, so readers are lenient: parsing ignores fields it does not know, and a
program built against an older stereod reads a newer one's messages. Writers are strict: every
message is built from typed fields and validated before it is sent. Field names of
:class:`ObjectsMessage` and :class:`ObjectState` are read by programs outside this project: keep
them stable. ``stereod schema`` prints the JSON Schema.
"""

from __future__ import annotations

import enum
import math
from typing import TYPE_CHECKING, Final, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from stereod.tracking.types import TrackLifecycle
from stereod.vision.geometry import Geometry

if TYPE_CHECKING:
    from stereod.pipeline import PairResult
    from stereod.tracking.types import TrackState

OBJECTS_SCHEMA: Final = "stereod.objects/1"
OBJECT_SCHEMA: Final = "stereod.object/1"
STATUS_SCHEMA: Final = "stereod.status/1"
STATS_SCHEMA: Final = "stereod.stats/1"
IMAGE_SCHEMA: Final = "stereod.image/1"
IMAGE_ENCODING: Final = "image/jpeg"
"""The encoding of an image sample's payload; its metadata is :class:`ImageInfo`, as JSON in
the sample's attachment."""

Vec3 = tuple[float, float, float]
Vec2 = tuple[float, float]
BBox = tuple[int, int, int, int]


def encoding_for(schema: str) -> str:
    """The Zenoh encoding string for a message schema."""
    return f"application/json;{schema}"


class EyeState(str, enum.Enum):
    """Health of one eye on the status key."""

    STARTING = "starting"
    """No frame yet since the daemon started."""
    STREAMING = "streaming"
    """Frames arrive."""
    DOWN = "down"
    """The eye failed (unplugged, I/O error); its source is reopening it."""
    ENDED = "ended"
    """A finite source (a file) has no more frames."""


class DaemonState(str, enum.Enum):
    """Where the daemon is in its life, on the status key."""

    STARTING = "starting"
    """The session is open; capture has not started."""
    RUNNING = "running"
    """Frames are processed."""
    DEGRADED = "degraded"
    """Running, but a live eye is down: no pairs until it is back."""
    STOPPING = "stopping"
    """A stop was asked for (SIGTERM, SIGINT, end of input): the queues drain."""
    FINISHED = "finished"
    """Everything was processed; the session is about to close."""
    FAILED = "failed"
    """The run ended with an error (the last of ``problems``); the session is about to
    close."""


class _Model(BaseModel):
    model_config = ConfigDict(extra="ignore", frozen=True, populate_by_name=True)


class EyeBlob(_Model):
    """A blob as one eye saw it (px, image coordinates, x right, y down)."""

    centroid_px: Vec2 = Field(description="Centre of gravity (eq. 5), px")
    bbox_px: BBox = Field(description="Bounding box x, y, width, height, px")
    area_px: int = Field(description="Foreground pixel count of the blob")


class ObjectState(_Model):
    """One tracked object at one capture instant; rig frame (X right, Y down, Z forward), SI."""

    schema_: Literal["stereod.object/1"] = Field(OBJECT_SCHEMA, alias="schema")
    track_id: int = Field(description="Stable id of the track; never reused while running")
    state: TrackLifecycle = Field(
        description="tentative (not yet confirmed), confirmed (seen in this pair), stationary "
        "(confirmed, seen in this pair, stopped: held out of the background, keeps its id when "
        "it moves on), coasting (confirmed, not seen in this pair: position and velocity are "
        "predicted, the blobs are the last seen)"
    )
    t_ns: int = Field(description="Capture instant, input's monotonic clock, ns")
    stamp_utc_ns: int = Field(description="Capture instant, UTC wall clock, ns")
    skew_ns: int = Field(description="Right minus left capture time of the pair, ns")
    position_m: Vec3 = Field(description="Position in the rig frame (Kalman filter), m")
    position_sigma_m: Vec3 = Field(description="One-sigma position error per axis, m")
    velocity_mps: Vec3 = Field(description="Velocity in the rig frame (Kalman filter), m/s")
    velocity_sigma_mps: Vec3 | None = Field(
        description="One-sigma velocity error per axis, m/s; null while unknown"
    )
    velocity_valid: bool = Field(
        description=(
            "False until the track is confirmed and its speed's own sigma is within 0.1 m/s"
            " or 10 % of the speed (tracking.valid_speed_sigma_*)"
        )
    )
    heading_valid: bool = Field(
        False,
        description=(
            "False until velocity_valid, the velocity's sigma across its direction on the"
            " ground is within the same bound and the heading's sigma within 15 deg: the"
            " direction is known, not only the speed (read as false when absent: a daemon older"
            " than this field)"
        ),
    )
    speed_mps: float = Field(description="|velocity| (eq. 22), m/s")
    speed_sigma_mps: float | None = Field(description="One-sigma speed error, m/s")
    heading_deg: float = Field(
        description="atan2(vx, vz) (eq. 23) in [0, 360): 0 away from the camera, 90 towards +X"
    )
    heading_sigma_deg: float | None = Field(description="One-sigma heading error, deg")
    raw_velocity_mps: Vec3 | None = Field(
        description="The paper's eq. 21 finite difference over the time base, m/s; null until "
        "the track spans it"
    )
    left: EyeBlob
    right: EyeBlob
    disparity_px: float = Field(description="x_left - x_right, px")
    size_m: float = Field(description="Blob width estimated from its bounding box and depth, m")
    age_s: float = Field(description="Time since the track started, s")
    extent_min_m: Vec3 | None = Field(
        None,
        description="Corner of the object's 3D box with the smallest x, y and z (left, top, "
        "near; rig frame, Y down), from its blobs' extent at its depth, as deep as wide, m",
    )
    extent_max_m: Vec3 | None = Field(
        None, description="Corner of the object's 3D box with the largest x, y and z, m"
    )


class Latency(_Model):
    """Where the time of one pair went (ms)."""

    detect_ms: float
    geometry_ms: float
    track_ms: float
    pipeline_ms: float = Field(description="Pair taken from the queue to message built, ms")
    queue_ms: float = Field(description="Pair formed to pair taken by the pipeline, ms")


class ObjectsMessage(_Model):
    """Everything measured from one stereo pair; published on ``<prefix>/<rig>/objects``."""

    schema_: Literal["stereod.objects/1"] = Field(OBJECTS_SCHEMA, alias="schema")
    rig: str
    seq: int = Field(description="Pair sequence number, from 0, gaps mean dropped pairs")
    t_ns: int = Field(description="Capture instant the measurements refer to, monotonic, ns")
    stamp_utc_ns: int = Field(description="The same instant on the UTC wall clock, ns")
    skew_ns: int = Field(description="Right minus left capture time, ns")
    left_seq: int = Field(description="Left frame's source sequence number")
    right_seq: int = Field(description="Right frame's source sequence number")
    geometry: Geometry
    calibration_id: str | None = None
    latency: Latency
    objects: list[ObjectState]


class EyeStatus(_Model):
    """Health of one eye."""

    state: EyeState
    fps: float = Field(description="Frames per second, over half a second at least")
    frames: int
    errors: int = Field(description="Frames the source reported as bad and skipped")
    last_error: str | None = None


class ClockDiscipline(_Model):
    """How the host's clock, which stamps ``stamp_utc_ns``, is kept on UTC (rigs fused in one
    room need their clocks within milliseconds of each other)."""

    source: Literal["chrony", "ptp", "unknown"] = Field(
        description="What disciplines it: chrony (chronyc tracking), PTP (linuxptp's pmc), "
        "or unknown (neither could be read)"
    )
    synchronised: bool | None = Field(None, description="Locked to its reference; null unknown")
    offset_s: float | None = Field(
        None,
        description="The clock minus its reference (chrony: system time; PTP: master offset), s",
    )
    state: str | None = Field(
        None, description="The source's own word: chrony's leap status, PTP's port state"
    )
    reference: str | None = Field(None, description="The reference (NTP server, grandmaster)")


class StatusMessage(_Model):
    """Daemon health, published on ``<prefix>/<rig>/status`` at 1 Hz and on change."""

    schema_: Literal["stereod.status/1"] = Field(STATUS_SCHEMA, alias="schema")
    rig: str
    state: DaemonState
    stamp_utc_ns: int
    uptime_s: float
    driver: str
    source: str
    left: EyeStatus
    right: EyeStatus
    pairs: int
    pairs_per_s: float
    published: int
    drops: dict[str, int] = Field(description="Frames or pairs lost, by reason")
    errors: dict[str, int] = Field(
        default_factory=dict,
        description="Frames that arrived unusable, were corrected, or failed to process, by reason",
    )
    reconnects: dict[str, int] = Field(
        default_factory=dict, description="Times each eye streamed again after being down"
    )
    skew_ms_mean: float | None = Field(
        description="Mean of |right - left| capture instants over the period, ms (no sign)"
    )
    skew_ms_max: float | None = Field(
        description="Largest |right - left| over the period, ms (objects' skew_ns has the sign)"
    )
    queue_depth: int
    geometry: Geometry
    calibration_id: str | None = None
    epipolar_residual_px: float | None = Field(
        description="Median |y_left - y_right| of matched blobs over the last period, px"
    )
    problems: list[str] = Field(description="Recent problems, newest last, one line each")
    notes: list[str] = Field(
        default_factory=list,
        description="Standing conditions that limit what the numbers mean (for example: no "
        "calibration, so depths rest on an assumed field of view)",
    )
    clock: ClockDiscipline | None = Field(
        None, description="How this host's UTC clock is disciplined; null from older daemons"
    )


class StatsMessage(_Model):
    """Counters since start, the reply of the ``<prefix>/<rig>/stats`` queryable."""

    schema_: Literal["stereod.stats/1"] = Field(STATS_SCHEMA, alias="schema")
    rig: str
    frames: dict[str, int]
    pairs: int
    published: int
    publish_errors: int
    drops: dict[str, int]
    errors: dict[str, int] = Field(default_factory=dict)
    reconnects: dict[str, int] = Field(default_factory=dict)
    queue_depth: int
    pipeline_ms_p50: float | None
    pipeline_ms_p99: float | None


class CanonicalGeometry(_Model):
    """The ``calibration`` queryable's reply when no calibration is in use: the canonical rig
    of eq. 9 the daemon assumes (its depth is only as good as the assumed field of view)."""

    geometry: Literal["canonical"] = "canonical"
    baseline_m: float = Field(description="Camera distance B, m")
    hfov_deg: float = Field(description="Assumed horizontal field of view, deg")
    width_px: int
    height_px: int
    focal_px: float = Field(description="f = x_0 / (2 tan(phi_0 / 2)), px")
    cx_px: float
    cy_px: float


class ImageInfo(_Model):
    """The attachment of an image on ``<prefix>/<rig>/image/<name>`` (the payload is the JPEG):
    which pair it shows, so a client can join it to that pair's ``objects`` message by ``seq``
    or ``t_ns``."""

    schema_: Literal["stereod.image/1"] = Field(IMAGE_SCHEMA, alias="schema")
    rig: str
    name: str = Field(description="left, right, overlay or mask")
    seq: int = Field(description="The pair's sequence number, as in its objects message")
    t_ns: int = Field(description="The pair's t_ns, as in its objects message, ns")
    stamp_utc_ns: int = Field(description="The same instant on the UTC wall clock, ns")
    width: int = Field(description="Image width, px")
    height: int = Field(description="Image height, px")


ALL_MESSAGES: dict[str, type[BaseModel]] = {
    OBJECTS_SCHEMA: ObjectsMessage,
    OBJECT_SCHEMA: ObjectState,
    STATUS_SCHEMA: StatusMessage,
    STATS_SCHEMA: StatsMessage,
    IMAGE_SCHEMA: ImageInfo,
}


def dump(msg: BaseModel) -> bytes:
    """Serialise a message to its JSON wire form (field aliases, e.g. ``schema``)."""
    return msg.model_dump_json(by_alias=True).encode()


def dump_objects(msg: ObjectsMessage) -> tuple[bytes, list[tuple[int, bytes]]]:
    """The ``objects`` payload and each object's own (track id, payload), :func:`dump`'s to
    the byte, with each object serialised once: the message's JSON is its other fields' and
    then, last, its objects'."""
    states = [dump(o) for o in msg.objects]
    head = msg.model_dump_json(by_alias=True, exclude={"objects"}).encode()
    payload = head[:-1] + b',"objects":[' + b",".join(states) + b"]}"
    return payload, [(o.track_id, state) for o, state in zip(msg.objects, states, strict=True)]


def _vec(a: np.ndarray) -> tuple[float, float, float]:
    x, y, z = a.tolist()
    return (x, y, z)


def _sigmas(cov: np.ndarray) -> tuple[float, float, float]:
    """The square roots of a (3, 3) covariance's diagonal (NaN where it is negative)."""
    x, y, z = (math.sqrt(v) if v >= 0 else math.nan for v in cov.diagonal().tolist())
    return (x, y, z)


def _finite(x: float) -> float | None:
    return x if math.isfinite(x) else None


def _blob(centroid: np.ndarray, bbox: np.ndarray, area: int) -> EyeBlob:
    x, y = centroid.tolist()[:2]
    bx, by, bw, bh = bbox.tolist()[:4]
    return EyeBlob(
        centroid_px=(float(x), float(y)), bbox_px=(int(bx), int(by), int(bw), int(bh)), area_px=area
    )


def object_state(s: TrackState, stamp_utc_ns: int, skew_ns: int) -> ObjectState:
    """The wire form of one track's state at ``stamp_utc_ns`` (UTC, ns)."""
    ob = s.observation
    vsig = _sigmas(s.velocity_cov)
    lo = hi = None
    if ob.extent_m is not None:
        # The blobs' boxes seen at the published depth: the observation's extent is their rays
        # cut at its own depth, which the filtered (or a coasting track's) position may not be.
        z_seen, z = float(ob.position_m[2]), float(s.position_m[2])
        k = z / z_seen if z_seen > 0 and z > 0 else 1.0
        lo = _vec(s.position_m + k * ob.extent_m[0])
        hi = _vec(s.position_m + k * ob.extent_m[1])
    return ObjectState(
        track_id=s.track_id,
        state=s.lifecycle,
        t_ns=s.t_ns,
        stamp_utc_ns=stamp_utc_ns,
        skew_ns=skew_ns,
        position_m=_vec(s.position_m),
        position_sigma_m=_sigmas(s.position_cov_m2),
        velocity_mps=_vec(s.velocity_mps),
        velocity_sigma_mps=vsig if all(map(math.isfinite, vsig)) else None,
        velocity_valid=s.velocity_valid,
        heading_valid=s.heading_valid,
        speed_mps=s.speed_mps,
        speed_sigma_mps=_finite(s.speed_sigma_mps),
        heading_deg=s.heading_deg,
        heading_sigma_deg=_finite(s.heading_sigma_deg),
        raw_velocity_mps=None if s.raw_velocity_mps is None else _vec(s.raw_velocity_mps),
        left=_blob(ob.left_image_px, ob.left_bbox_px, ob.left_area_px),
        right=_blob(ob.right_image_px, ob.right_bbox_px, ob.right_area_px),
        disparity_px=ob.disparity_px,
        size_m=ob.size_m,
        age_s=s.age_s,
        extent_min_m=lo,
        extent_max_m=hi,
    )


def objects_message(
    result: PairResult,
    *,
    rig: str,
    geometry: Geometry,
    calibration_id: str | None,
    utc_offset_ns: int,
    queue_ms: float = 0.0,
) -> ObjectsMessage:
    """The ``objects`` message of one pair: ``utc_offset_ns`` is the wall clock minus the
    frames' monotonic clock (ns); ``queue_ms`` how long the pair waited for the pipeline."""
    stamp = result.t_ns + utc_offset_ns
    t = result.timings
    return ObjectsMessage(
        rig=rig,
        seq=result.seq,
        t_ns=result.t_ns,
        stamp_utc_ns=stamp,
        skew_ns=result.skew_ns,
        left_seq=result.left_seq,
        right_seq=result.right_seq,
        geometry=geometry,
        calibration_id=calibration_id,
        latency=Latency(
            detect_ms=t.detect_ms,
            geometry_ms=t.geometry_ms,
            track_ms=t.track_ms,
            pipeline_ms=t.pipeline_ms,
            queue_ms=queue_ms,
        ),
        objects=[object_state(s, stamp, result.skew_ns) for s in result.tracks],
    )
