"""Daemon configuration: one TOML file, ``STEREOD_...`` environment overrides, flags on top.

Precedence, highest first: command-line flags, environment (``STEREOD_DETECTOR__BETA=0.05``:
section and field joined by a double underscore), the TOML file, the defaults below. The three
are merged and every value validated once by the pydantic models below (a small layer of our
own reads the environment: pydantic-settings would cost the daemon 16 MB of memory).
:func:`load_config` turns a failure into one :class:`~stereod.errors.ConfigError` line naming
where the value came from, the field, the value and what is allowed.

Example::

    [rig]
    name = "bench"
    baseline_m = 0.060     # m, the Minoru's
    hfov_deg = 60.0        # deg, horizontal field of view of one eye

    [driver]
    name = "replay"
    [driver.options]
    path = "/var/lib/stereod/run1"
"""

from __future__ import annotations

import json
import os
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
)

from stereod.bus import keys
from stereod.daemon.config_section import Section, field_names, pipeline_default
from stereod.daemon.config_tracking import TrackingConfig
from stereod.daemon.config_zenoh import ZenohConfig as ZenohConfig
from stereod.errors import ConfigError, UsageError, describe_error
from stereod.files.bounds import (
    ABSORB_S,
    BASELINE_M,
    CENTROID_SIGMA_PX,
    HFOV_DEG,
    IMAGE_RATE_HZ,
    READOUT_S,
    STATUS_PERIOD_S,
    THRESHOLD_GREY,
    TOLERANCE_MS,
)
from stereod.files.config_input import ENV_OTHER, ENV_PREFIX, merge, origin, prune, read_toml
from stereod.files.nesting import check_depth
from stereod.files.paths import TextPath
from stereod.sources.pairing import DEFAULT_TOLERANCE_NS
from stereod.vision.detect_params import (
    MAX_WARMUP_FRAMES,
    Centroid,
    DetectorParams,
    Luminance,
    Warmup,
)
from stereod.vision.geometry.matching import MatchParams
from stereod.vision.geometry.refine import RefineParams
from stereod.vision.grouping import GroupParams

# The defaults of the pipeline's settings are stated once, in its parameter classes.
_DETECT = DetectorParams()
_MATCH = MatchParams()
_REFINE = RefineParams()
_GROUP = GroupParams()


class RigConfig(Section):
    """The stereo rig: its name in key expressions and the canonical geometry (eq. 9)."""

    name: str = Field(keys.DEFAULT_RIG, pattern=keys.RIG_PATTERN, description="Rig name in keys")
    # Bounds and their reasons: stereod.files.bounds (a Minoru's 0.060 m; UVC webcams' lenses).
    baseline_m: Annotated[float, BASELINE_M.validator()] = Field(
        0.060, description="Camera distance B, m"
    )
    hfov_deg: Annotated[float, HFOV_DEG.validator()] = Field(
        60.0, description="Horizontal field of view, deg"
    )
    calibration: TextPath | None = Field(
        None, description="Calibration file (stereod calibrate); without it, the canonical rig"
    )
    readout_s: Annotated[float, READOUT_S.validator()] = Field(
        pipeline_default("readout_s"),
        description="Rolling shutter: time from the first image row to the last, s (0: global "
        "shutter); a frame is at most a tenth of a second long at 10 Hz",
    )


class DriverConfig(Section):
    """Which frame source to open (entry point group ``stereod.drivers``) and its own options."""

    name: str = Field("v4l2_minoru", description="replay, synthetic, v4l2_minoru, or a plug-in")
    options: dict[str, Any] = Field(default_factory=dict)


class DetectorConfig(Section):
    """Paper sec. II parameters and what is added to them (see
    :class:`stereod.vision.detect_params.DetectorParams`)."""

    beta: float = Field(
        _DETECT.beta, ge=0.0, lt=1.0, description="Background update, eq. 3, per frame"
    )
    threshold: Annotated[float, THRESHOLD_GREY.validator()] = Field(
        _DETECT.threshold, description="t of eq. 4, grey levels"
    )
    min_area_px: int = Field(_DETECT.min_area_px, ge=1, le=10**7, description="Smallest blob, px")
    warmup_frames: int = Field(
        _DETECT.warmup_frames,
        ge=1,
        le=MAX_WARMUP_FRAMES,
        description="Frames in the initial background",
    )
    warmup: Warmup = Field(_DETECT.warmup, description="median or mean of the warm-up frames")
    open_px: int = Field(
        _DETECT.open_px, ge=0, le=31, description="Opening kernel side, px; 0 disables"
    )
    close_px: int = Field(
        _DETECT.close_px, ge=0, le=31, description="Closing kernel side, px; 0 disables"
    )
    luminance: Luminance = Field(_DETECT.luminance, description="bt601 or mean (eq. 2 exactly)")
    centroid: Centroid = Field(
        _DETECT.centroid, description="matte, coverage or binary (eq. 5): how edge pixels weigh"
    )
    color: bool = Field(_DETECT.color, description="Difference colour frames per channel")
    hold_foreground: bool = Field(
        _DETECT.hold_foreground, description="Do not learn the background under foreground"
    )
    hold_margin_px: int = Field(
        _DETECT.hold_margin_px, ge=0, le=50, description="Growth of the held foreground, px"
    )
    absorb_s: Annotated[float, ABSORB_S.validator()] = Field(
        _DETECT.absorb_s, description="Foreground still this long becomes background, s"
    )
    fill_holes: bool = Field(_DETECT.fill_holes, description="An object's support is filled")
    convex: bool = Field(_DETECT.convex, description="An object's support is convex")
    merge_gap: float = Field(
        _DETECT.merge_gap, ge=0.0, le=10.0, description="Pieces this close are one object"
    )
    max_foreground: float = Field(
        _DETECT.max_foreground,
        ge=0.01,
        le=1.0,
        description="Share of the image above which a foreground is a near object only if "
        "neither changed light nor a moved camera explains it (without near_objects: no blobs)",
    )
    max_blobs: int = Field(
        _DETECT.max_blobs, ge=1, le=100000, description="More blobs than this: saturated"
    )
    gain: bool = Field(_DETECT.gain, description="Follow a global change of brightness at once")
    hysteresis: float = Field(
        _DETECT.hysteresis,
        ge=0.0,
        le=1.0,
        description="Differences down to this share of the threshold join foreground they touch",
    )
    grow_px: int = Field(_DETECT.grow_px, ge=0, le=50, description="Hysteresis reach per step, px")
    learn_stride: int = Field(
        _DETECT.learn_stride,
        ge=1,
        le=16,
        description="Eq. 3 updates every n-th row each frame, in turn, at the same time constant",
    )
    disc_max_px: int = Field(
        _DETECT.disc_max_px,
        ge=0,
        le=256,
        description="Round blobs up to this size, px, are centred by a disc fitted to them; 0: off",
    )
    shadows: bool = Field(
        _DETECT.shadows, description="Leave cast shadows (darkened background) out of objects"
    )
    shadow_ratio: tuple[float, float] = Field(
        _DETECT.shadow_ratio,
        description="A shadow darkens the background to between these shares of its brightness",
    )

    near_objects: bool = Field(
        _DETECT.near_objects,
        description="A large foreground is an object unless changed light or a moved camera "
        "explains it",
    )

    @field_validator("shadow_ratio")
    @classmethod
    def _ratio_order(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not 0.0 < v[0] < v[1] < 1.0:
            raise ValueError("must be two shares with 0 < lower < upper < 1, e.g. [0.15, 0.92]")
        return v

    def params(self) -> DetectorParams:
        return DetectorParams(**self.model_dump())


class PairingConfig(Section):
    """How the two eyes are paired by timestamp."""

    tolerance_ms: Annotated[float, TOLERANCE_MS.validator()] = Field(
        DEFAULT_TOLERANCE_NS / 1e6, description="Largest |skew|, ms"
    )
    max_pending: int = Field(8, ge=2, le=1000, description="Frames one eye may wait, count")
    skew_compensation: bool = Field(
        pipeline_default("skew_compensation"), description="Bring both eyes to one instant"
    )


class MatchingConfig(Section):
    """How blobs are matched between the eyes (``MatchParams``, ``vision/geometry/matching.py``)."""

    row_tolerance_px: float = Field(
        _MATCH.row_tolerance_px, gt=0.0, description="Largest |y_L - y_R|, px"
    )
    row_tolerance_share: float = Field(
        _MATCH.row_tolerance_share,
        ge=0.0,
        lt=1.0,
        description="For two blobs clear of the image's border with one end on one row, the "
        "row tolerance grows to this share of the shorter one's height (0: never)",
    )
    min_disparity_px: float = Field(
        _MATCH.min_disparity_px, ge=0.0, description="Smallest x_L - x_R, px"
    )
    max_disparity_px: float = Field(
        _MATCH.max_disparity_px,
        gt=0.0,
        validate_default=True,  # checked against min_disparity_px even when left out
        description="Largest x_L - x_R, px",
    )
    max_area_ratio: float = Field(
        _MATCH.max_area_ratio, ge=1.0, description="Largest blob area ratio"
    )

    @field_validator("max_disparity_px")
    @classmethod
    def _above_min(cls, v: float, info: ValidationInfo) -> float:
        low = info.data.get("min_disparity_px")
        if low is not None and not v > low:
            raise ValueError(
                f"must be larger than min_disparity_px ({low:g}): nothing can match; lower "
                "min_disparity_px or raise max_disparity_px"
            )
        return v

    centroid_sigma_px: Annotated[float, CENTROID_SIGMA_PX.validator()] = Field(
        pipeline_default("centroid_sigma_px"), description="Centroid error per axis, px"
    )
    silhouette_depth: bool = Field(
        pipeline_default("silhouette_depth"),
        description="Depth at the object's centre, not where its silhouettes triangulate",
    )

    def params(self) -> MatchParams:
        return MatchParams(**self.model_dump(exclude={"centroid_sigma_px", "silhouette_depth"}))


class GroupingConfig(Section):
    """Which matched blob pairs are one object (``GroupParams`` in ``vision/grouping.py``)."""

    enabled: bool = Field(_GROUP.enabled, description="Group blob pairs into objects by depth")
    max_object_size_m: float = Field(
        _GROUP.max_object_size_m,
        ge=0.05,
        le=20.0,
        description="Largest width, height and depth of what pieces grouped into one object "
        "span, m (a standing person: 1.8; one blob wider, several people in it, stays one)",
    )
    max_gap_m: float = Field(
        _GROUP.max_gap_m, ge=0.0, le=5.0, description="Largest gap between pieces of one object, m"
    )

    disparity_margin_px: float = Field(
        _GROUP.disparity_margin_px,
        ge=0.0,
        le=50.0,
        description=(
            "Pieces' disparities may differ by this beyond their depth, px (twice this for a "
            "piece whose two eyes' outlines disagree)"
        ),
    )

    def params(self) -> GroupParams:
        return GroupParams(**self.model_dump())


class RefineConfig(Section):
    """Disparity by appearance matching (``RefineParams``, ``vision/geometry/refine.py``)."""

    enabled: bool = Field(_REFINE.enabled, description="Match the left patch along the right row")
    margin_px: int = Field(_REFINE.margin_px, ge=0, le=50, description="Template margin, px")
    search_px: float = Field(_REFINE.search_px, gt=0.0, le=200.0, description="Search reach, px")
    search_rel: float = Field(
        _REFINE.search_rel, ge=0.0, le=5.0, description="Or this share of the blob's width"
    )
    rows_px: int = Field(_REFINE.rows_px, ge=0, le=20, description="Rows searched either way")
    erode_px: int = Field(_REFINE.erode_px, ge=0, le=20, description="Template mask shrink, px")
    min_score: float = Field(
        _REFINE.min_score, ge=-1.0, le=1.0, description="Weaker matches keep the centroids"
    )

    def params(self) -> RefineParams:
        return RefineParams(**self.model_dump())


class DaemonConfig(Section):
    """Threads, queues and reporting."""

    queue_size: int = Field(4, ge=1, le=1000, description="Pairs waiting for the pipeline")
    publish_queue_size: int = Field(16, ge=1, le=10000, description="Messages waiting to go out")
    status_period_s: Annotated[float, STATUS_PERIOD_S.validator()] = Field(
        1.0, description="Status interval, s"
    )
    detect_workers: int = Field(
        2,
        ge=1,
        le=2,
        description="Threads detecting the two eyes (the second from 0.5 Mpx a frame)",
    )
    image_rate_hz: Annotated[float, IMAGE_RATE_HZ.validator()] = Field(
        5.0, description="Images per second while subscribed; 0 never"
    )
    image_quality: int = Field(80, ge=1, le=100, description="JPEG quality of images, 1-100")
    log_level: Literal["DEBUG", "INFO", "WARNING", "ERROR"] = "INFO"
    detect: bool = Field(
        True,
        description="Detect and track objects; false publishes an empty objects message per "
        "pair (a benchmark's floor: capture, pairing and publishing alone)",
    )


Ros2Topic = Literal["odom", "markers", "camera_info", "images", "tf_static", "objects"]
_ROS2_TOPICS: tuple[Ros2Topic, ...] = ("odom", "markers", "camera_info", "images", "tf_static")


class Ros2Config(Section):
    """ROS 2 live (``ros/ros2_live.py``): the daemon also speaks rmw_zenoh (Jazzy, Kilted)."""

    enabled: bool = Field(False, description="Publish the ROS 2 topics as an rmw_zenoh node")
    domain_id: int = Field(0, ge=0, le=232, description="ROS_DOMAIN_ID of the ROS machines")
    namespace: str = Field(
        "",
        pattern=r"^/?([A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*)?/?$",
        description="Node namespace, also prefixed to the stereod topics ('' for none); ROS "
        "names: letters, digits, '_', parts split by '/', each starting with a letter",
    )
    topics: list[Ros2Topic] = Field(
        default_factory=lambda: list(_ROS2_TOPICS),
        description="Topic groups to publish",
    )


class StereodConfig(BaseModel):
    """The whole configuration; sections mirror the TOML tables."""

    model_config = ConfigDict(extra="forbid")

    rig: RigConfig = Field(default_factory=RigConfig)
    driver: DriverConfig = Field(default_factory=DriverConfig)
    detector: DetectorConfig = Field(default_factory=DetectorConfig)
    pairing: PairingConfig = Field(default_factory=PairingConfig)
    matching: MatchingConfig = Field(default_factory=MatchingConfig)
    tracking: TrackingConfig = Field(default_factory=TrackingConfig)
    refine: RefineConfig = Field(default_factory=RefineConfig)
    grouping: GroupingConfig = Field(default_factory=GroupingConfig)
    zenoh: ZenohConfig = Field(default_factory=ZenohConfig)
    daemon: DaemonConfig = Field(default_factory=DaemonConfig)
    ros2: Ros2Config = Field(default_factory=Ros2Config)


def environment(environ: Mapping[str, str] | None = None) -> dict[str, Any]:
    """The configuration that ``STEREOD_<SECTION>__<FIELD>`` variables set, as nested tables
    (``STEREOD_DRIVER__OPTIONS__FPS`` reaches into the driver's options). A list, pair or
    table value is JSON; a variable that names no field is refused, as an unknown TOML key is."""
    env = os.environ if environ is None else environ
    out: dict[str, Any] = {}
    older: dict[str, set[str]] = {}  # field -> sections where an older name of it was set
    for name, value in sorted(env.items()):
        upper = name.upper()
        if not upper.startswith(ENV_PREFIX) or upper in ENV_OTHER:
            continue
        parts = name[len(ENV_PREFIX) :].lower().split("__")
        section = StereodConfig.model_fields.get(parts[0])
        fields = getattr(section.annotation, "model_fields", {}) if section else {}
        fld = None
        if len(parts) > 1:
            fld = fields.get(parts[1])
            kind = section.annotation if section else None
            if fld is None and isinstance(kind, type) and issubclass(kind, Section):
                # an older name the field is read by: taken under the field's own
                owner = next((n for n, ns in field_names(kind).items() if parts[1] in ns), None)
                if owner is not None:
                    fld = fields[owner]
                    if owner in out.get(parts[0], {}) or parts[0] in older.get(owner, ()):
                        raise ConfigError(
                            f"environment variable {name}: the older name of "
                            f"STEREOD_{parts[0].upper()}__{owner.upper()}, which is set too: "
                            "set one of them"
                        )
                    older.setdefault(owner, set()).add(parts[0])
                    parts = [parts[0], owner, *parts[2:]]
            elif fld is not None and parts[0] in older.get(parts[1], ()):
                raise ConfigError(
                    f"environment variable {name}: an older name of it is set too: set one of them"
                )
        if fld is None or (len(parts) > 2 and typing.get_origin(fld.annotation) is not dict):
            raise ConfigError(
                f"environment variable {name}: names no configuration field (use "
                "STEREOD_<SECTION>__<FIELD>, e.g. STEREOD_DETECTOR__BETA; see stereod run --check)"
            )
        parsed: Any = value
        # a field that holds a list or table; or an entry of a table of options (a driver's,
        # whose types its driver knows) that reads as a JSON list or table (else it is text,
        # for the driver to read: a path may start with "[")
        nested = len(parts) > 2 and value.lstrip()[:1] in ("[", "{")
        holder = typing.get_origin(fld.annotation) in (list, tuple, dict)
        if nested or (len(parts) == 2 and holder):
            where = f"environment variable {name}"
            check_depth(value, "json", where, ConfigError)
            try:
                parsed = json.loads(value)
            except ValueError:
                if nested:
                    parsed = value
                else:
                    raise ConfigError(
                        f"environment variable {name}={value!r}: a list or table is written as "
                        "JSON, e.g. STEREOD_ZENOH__CONNECT='[\"tcp/127.0.0.1:7447\"]'"
                    ) from None
        node = out
        for part in parts[:-1]:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ConfigError(
                    f"environment variable {name}: another variable sets "
                    f"{'.'.join(parts[:-1])} as a whole; set the table or its fields, not both"
                )
        if isinstance(node.get(parts[-1]), dict):
            raise ConfigError(
                f"environment variable {name}: other variables set fields of "
                f"{'.'.join(parts)}; set the table or its fields, not both"
            )
        node[parts[-1]] = parsed
    return out


def canonical_names(data: dict[str, Any], where: str) -> dict[str, Any]:
    """``data``'s tables with a field given by an older name put under its own, so that a
    later source (the environment, a flag) giving it by either name wins as for any field;
    one given under both names in ``data`` (read from ``where``) is refused."""
    out = dict(data)
    for section, table in data.items():
        fld = StereodConfig.model_fields.get(section)
        kind = fld.annotation if fld else None
        if not (isinstance(table, dict) and isinstance(kind, type) and issubclass(kind, Section)):
            continue
        for name, names in field_names(kind).items():
            given = [n for n in names if n in table]
            if len(given) > 1:
                raise ConfigError(
                    f"{where}: {section}.{given[1]} is the older name of {section}.{name}, "
                    "which is given too: give one of them"
                )
            if given and given[0] != name:
                table = {(name if k == given[0] else k): v for k, v in table.items()}
        out[section] = table
    return out


def load_config(path: Path | None = None, overrides: dict[str, Any] | None = None) -> StereodConfig:
    """Build the configuration from ``path`` (TOML), the environment and ``overrides`` (flags),
    later ones winning, and validate it once.

    ``overrides`` is a nested dict like ``{"detector": {"beta": 0.05}}``; ``None`` values are
    ignored so unset flags do not mask the file. A flag that names another driver than the
    file names leaves the file's driver options out (they are that other driver's); a file
    that names none gives its options to whichever driver runs.
    """
    data = canonical_names(read_toml(path), str(path)) if path is not None else {}
    flags = prune(overrides or {})
    env = environment()
    below = merge(data, env)
    named = flags.get("driver", {}).get("name") if isinstance(flags.get("driver"), dict) else None
    under = below.get("driver")
    if isinstance(under, dict) and named is not None and under.get("name", named) != named:
        below = {**below, "driver": {k: v for k, v in under.items() if k != "options"}}
    try:
        return StereodConfig.model_validate(merge(below, flags))
    except ValidationError as exc:
        errors = [
            (origin(tuple(e["loc"]), path, flags, (data, env)), e)
            for e in exc.errors(include_url=False)
        ]
        parts = [
            f"{origin}: invalid config: {describe_error(e, model=StereodConfig)}"
            for origin, e in errors
        ]
        if all(origin == "command line" for origin, _ in errors):
            raise UsageError("; ".join(parts)) from exc  # a bad flag, exit 64
        raise ConfigError("; ".join(parts)) from exc
