"""Wire messages published on Zenoh (design sec. 4), defined once as pydantic models.

Payloads are JSON with encoding ``application/json;stereod.<message>/<version>``; every message
has a ``schema`` field with that ``stereod.<message>/<version>`` string. Within a version fields
are only ever added. Field names of :class:`ObjectsMessage` and :class:`ObjectState` are read by
programs outside this project: keep them stable. ``stereod schema`` prints the JSON Schema.
"""

from __future__ import annotations

from typing import Final, Literal

from pydantic import BaseModel, ConfigDict, Field

OBJECTS_SCHEMA: Final = "stereod.objects/1"
OBJECT_SCHEMA: Final = "stereod.object/1"
STATUS_SCHEMA: Final = "stereod.status/1"
STATS_SCHEMA: Final = "stereod.stats/1"

Vec3 = tuple[float, float, float]
Vec2 = tuple[float, float]
BBox = tuple[int, int, int, int]


def encoding_for(schema: str) -> str:
    """The Zenoh encoding string for a message schema."""
    return f"application/json;{schema}"


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class EyeBlob(_Model):
    """A blob as one eye saw it (px, image coordinates, x right, y down)."""

    centroid_px: Vec2 = Field(description="Centre of gravity (eq. 5), px")
    bbox_px: BBox = Field(description="Bounding box x, y, width, height, px")
    area_px: int = Field(description="Foreground pixel count of the blob")


class ObjectState(_Model):
    """One tracked object at one capture instant; rig frame (X right, Y down, Z forward), SI."""

    schema_: Literal["stereod.object/1"] = Field(OBJECT_SCHEMA, alias="schema")
    track_id: int = Field(description="Stable id of the track; never reused while running")
    state: Literal["tentative", "confirmed", "coasting"] = Field(
        description="tentative (not yet confirmed), confirmed (seen in this pair), coasting "
        "(confirmed, not seen in this pair: position and velocity are predicted, the blobs are "
        "the last seen)"
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
        description="False until the track is confirmed and has lived for the time base"
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

    model_config = ConfigDict(extra="forbid", frozen=True, populate_by_name=True)


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
    geometry: Literal["canonical", "calibrated"]
    calibration_id: str | None = None
    latency: Latency
    objects: list[ObjectState]

    model_config = ConfigDict(extra="forbid", frozen=True, populate_by_name=True)


class EyeStatus(_Model):
    """Health of one eye."""

    state: Literal["starting", "streaming", "down", "ended"]
    fps: float = Field(description="Frames per second over the last status period")
    frames: int
    errors: int = Field(description="Frames the source reported as bad and skipped")
    last_error: str | None = None


class StatusMessage(_Model):
    """Daemon health, published on ``<prefix>/<rig>/status`` at 1 Hz and on change."""

    schema_: Literal["stereod.status/1"] = Field(STATUS_SCHEMA, alias="schema")
    rig: str
    state: Literal["starting", "running", "degraded", "stopping", "finished"]
    stamp_utc_ns: int
    uptime_s: float
    driver: str
    source: str
    left: EyeStatus
    right: EyeStatus
    pairs: int
    pairs_per_s: float
    published: int
    drops: dict[str, int] = Field(description="Frames or pairs dropped, by reason")
    skew_ms_mean: float | None
    skew_ms_max: float | None
    queue_depth: int
    geometry: Literal["canonical", "calibrated"]
    calibration_id: str | None = None
    epipolar_residual_px: float | None = Field(
        description="Median |y_left - y_right| of matched blobs over the last period, px"
    )
    problems: list[str] = Field(description="Recent problems, newest last, one line each")

    model_config = ConfigDict(extra="forbid", frozen=True, populate_by_name=True)


class StatsMessage(_Model):
    """Counters since start, the reply of the ``<prefix>/<rig>/stats`` queryable."""

    schema_: Literal["stereod.stats/1"] = Field(STATS_SCHEMA, alias="schema")
    rig: str
    frames: dict[str, int]
    pairs: int
    published: int
    publish_errors: int
    drops: dict[str, int]
    queue_depth: int
    pipeline_ms_p50: float | None
    pipeline_ms_p99: float | None

    model_config = ConfigDict(extra="forbid", frozen=True, populate_by_name=True)


ALL_MESSAGES: dict[str, type[BaseModel]] = {
    OBJECTS_SCHEMA: ObjectsMessage,
    OBJECT_SCHEMA: ObjectState,
    STATUS_SCHEMA: StatusMessage,
    STATS_SCHEMA: StatsMessage,
}


def dump(msg: BaseModel) -> bytes:
    """Serialise a message to its JSON wire form (field aliases, e.g. ``schema``)."""
    return msg.model_dump_json(by_alias=True).encode()
