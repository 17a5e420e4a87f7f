"""The ``[tracking]`` section of the daemon's configuration: association, the Kalman
filters and the lifecycle (:class:`stereod.tracking.types.TrackerParams`, whose defaults it
states once), and whether tracks hold the background under them."""

from __future__ import annotations

import math
from typing import Annotated

from pydantic import AliasChoices, Field, field_validator, model_validator

from stereod.daemon.config_section import Section, pipeline_default
from stereod.files.bounds import (
    HOLD_STILL_S,
    MANOEUVRE_CHI2,
    MAX_COAST_S,
    MAX_HIDDEN_S,
    MAX_MEMBER_S,
    STILL_AFTER_S,
    TIME_BASE_S,
)
from stereod.tracking.types import TrackerParams

_TRACK = TrackerParams()


class TrackingConfig(Section):
    """Association, Kalman filter and lifecycle (``TrackerParams`` in ``tracking/types.py``)."""

    gate_px: float = Field(
        _TRACK.gate_px, gt=0.0, le=1000.0, description="Image gate around a prediction, px"
    )
    motion_gate: float = Field(
        _TRACK.motion_gate, ge=0.0, le=10.0, description="Gate growth per px of image motion"
    )
    max_speed_mps: float = Field(
        _TRACK.max_speed_mps, gt=0.0, le=1000.0, description="Fastest object to follow, m/s"
    )
    manoeuvre_chi2: Annotated[float, MANOEUVRE_CHI2.validator()] = Field(
        _TRACK.manoeuvre_chi2, description="Mahalanobis bound of a manoeuvre, 3 dof"
    )
    manoeuvre_sigma_mps: float = Field(
        _TRACK.manoeuvre_sigma_mps,
        gt=0.0,
        le=1000.0,
        description="Velocity sigma of a track before its filter starts, m/s",
    )
    accel_noise: float = Field(
        _TRACK.accel_noise, gt=0.0, le=1e6, description="White acceleration density, m^2/s^3"
    )
    time_base_s: Annotated[float, TIME_BASE_S.validator()] = Field(
        _TRACK.time_base_s, description="tau of eq. 21, s"
    )
    max_coast_s: Annotated[float, MAX_COAST_S.validator()] = Field(
        _TRACK.max_coast_s, description="Track lives unseen, s"
    )
    max_hidden_s: Annotated[float, MAX_HIDDEN_S.validator()] = Field(
        _TRACK.max_hidden_s,
        description="Track lives unseen this long while both eyes see a blob where it should "
        "be (behind another object), s",
    )
    max_member_s: Annotated[float, MAX_MEMBER_S.validator()] = Field(
        _TRACK.max_member_s,
        description="A track taken into another's object (a box a robot pushes) is kept this "
        "long, unpublished, for what comes out of that object to take its id again, s",
    )
    confirm_hits: int = Field(
        _TRACK.confirm_hits, ge=1, le=1000, description="Observations to confirm a track"
    )
    valid_speed_sigma_mps: float = Field(
        _TRACK.valid_speed_sigma_mps,
        gt=0.0,
        le=10.0,
        description="Speed sigma for a valid velocity, m/s (a speed known no better than 10 m/s "
        "is not known)",
    )
    valid_speed_sigma_rel: float = Field(
        _TRACK.valid_speed_sigma_rel, ge=0.0, le=1.0, description="Or this share of the speed"
    )
    hold_still_s: Annotated[float, HOLD_STILL_S.validator()] = Field(
        _TRACK.hold_still_s,
        validation_alias=AliasChoices("hold_still_s", "freeze_s"),
        description="A stopped object is held out of the background, keeping its id, this long, s "
        "(past still_after_s; freeze_s, its older name, is read too)",
    )
    size_gate: float = Field(
        _TRACK.size_gate,
        ge=0.0,
        le=5.0,
        description="A track's gate is at least this share of its blob's size (sqrt of area)",
    )
    merge_depth_m: float = Field(
        _TRACK.merge_depth_m,
        ge=0.0,
        le=10.0,
        description="Tracks one blob holds within this depth of each other ...",
    )
    merge_speed_mps: float = Field(
        _TRACK.merge_speed_mps,
        ge=0.0,
        le=10.0,
        description="... and moving together within this are one object, m/s",
    )
    still_after_s: Annotated[float, STILL_AFTER_S.validator()] = Field(
        _TRACK.still_after_s,
        description="Not seen moving this long: the object is stationary, s",
    )
    stationary_mps: float = Field(
        _TRACK.stationary_mps,
        ge=0.0,
        le=1.0,
        description="Below this an object is stopped, m/s (a slow walk is 1 m/s)",
    )
    gravity_mps2: tuple[float, float, float] = Field(
        _TRACK.gravity_mps2,
        description="Gravity in the rig frame (Y down in a level rig), m/s^2; [0, 0, 0]: off",
    )
    freeze_background: bool = Field(
        pipeline_default("freeze_background"), description="Do not learn background under tracks"
    )

    @field_validator("gravity_mps2")
    @classmethod
    def _gravity_finite(cls, v: tuple[float, float, float]) -> tuple[float, float, float]:
        if not all(math.isfinite(c) and abs(c) <= 100.0 for c in v):
            raise ValueError("each component must be finite and at most 100 m/s^2")
        return v

    @model_validator(mode="after")
    def _held_once_stopped(self) -> TrackingConfig:
        """A stopped object is held beyond the moment it counts as stopped: a
        ``still_after_s`` beyond the default hold lengthens the hold by it (the default hold
        then counts from there; the hold stays unset, as given); a hold given shorter (but
        not 0, never) is refused."""
        if 0.0 < self.hold_still_s < self.still_after_s:
            if "hold_still_s" not in self.model_fields_set:
                self.hold_still_s = min(self.hold_still_s + self.still_after_s, HOLD_STILL_S.hi)
                self.model_fields_set.discard("hold_still_s")
                return self
            raise ValueError(
                f"hold_still_s {self.hold_still_s:g} s is shorter than still_after_s "
                f"{self.still_after_s:g} s: a stopped object would be learned into the "
                "background before it counts as stopped; make it at least still_after_s, or 0 "
                "never to hold one"
            )
        return self

    def params(self) -> TrackerParams:
        return TrackerParams(**self.model_dump(exclude={"freeze_background"}))
