"""What the fusion node says about itself on ``<prefix>/rooms/<room>/status`` and replies on
its ``stats`` queryable (``stereod.fuse_status/1``): each rig's link, the room's tracks, and
where the fusion's time goes."""

from __future__ import annotations

from typing import Final, Literal

from pydantic import BaseModel, ConfigDict, Field

FUSE_STATUS_SCHEMA: Final = "stereod.fuse_status/1"
WINDOW: Final = 1000
"""The last steps whose times, and the last rig messages whose added latencies, make the
status's p50 and p99."""


class _Model(BaseModel):
    model_config = ConfigDict(extra="ignore", frozen=True, populate_by_name=True)


class RigLink(_Model):
    """One rig as the fusion node hears it."""

    live: bool = Field(description="A message arrived within the rig timeout")
    messages: int = Field(description="Objects messages received since start")
    tracks: int = Field(description="The rig's tracks in its latest message (not tentative)")
    last_stamp_utc_ns: int | None = Field(description="Its latest message's UTC stamp, ns")
    restarts: int = Field(description="Times its sequence numbers started again")
    clock_offset_ms: float | None = Field(
        None,
        description="Its clock minus the reference rig's, from objects both saw, ms; null "
        "until enough shared observations",
    )
    clock_samples: int = Field(0, description="Shared observations behind clock_offset_ms")
    clock_off: bool = Field(False, description="|clock_offset_ms| is beyond the bound")
    clock_sigma_ms: float | None = Field(
        None, description="clock_offset_ms's standard error, ms; null with it"
    )
    clock_correction_ms: float = Field(
        0.0,
        description="What its stamps are corrected by before fusion: its offset once the "
        "standard error is within 5 ms over 60 observations or more, held since, else 0, ms",
    )


class FuseStatus(_Model):
    """The fusion node's health, at the status period and on a subscriber's arrival."""

    schema_: Literal["stereod.fuse_status/1"] = Field(FUSE_STATUS_SCHEMA, alias="schema")
    room: str
    state: Literal["running", "stopping"]
    stamp_utc_ns: int
    uptime_s: float
    rigs: dict[str, RigLink]
    tracks: int = Field(description="Room tracks at the last step")
    steps: int = Field(
        description="Fusion steps since start (each publishes the room tracks it touched on "
        "their own keys; the room's whole message goes out at most --max-rate times a second)"
    )
    published: int
    steps_per_s: float
    fuse_ms_p50: float | None = Field(
        description=f"One step's own time, median over the last {WINDOW} steps, ms"
    )
    fuse_ms_p99: float | None
    added_ms_p50: float | None = Field(
        description="Rig message received to its room tracks published, median over the last "
        f"{WINDOW} rig messages, ms"
    )
    added_ms_p99: float | None
    added_ms_edges: list[float] = Field(
        default_factory=list, description="Upper edges of added_ms_counts' bins, ms"
    )
    added_ms_counts: list[int] = Field(
        default_factory=list,
        description="Rig messages since start by added latency: each count those up to its "
        "edge and above the one before (the first from 0 ms), one more count beyond the last "
        "edge. Two replies' difference gives the percentiles between them (the same node: "
        "uptime_s grew, and no count went down)",
    )
    clock_bound_ms: float = Field(description="A rig clock off by more is flagged, ms")
    problems: list[str] = Field(description="Standing problems, one line each")
