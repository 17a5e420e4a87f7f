"""The ``[zenoh]`` section of the configuration, apart from the others: every program that
opens a session (the daemon, ``stereod subscribe``, a client of :mod:`stereod.client`) reads
it, and none but the daemon needs the pipeline's settings."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from stereod.bus import keys
from stereod.bus.endpoints import Endpoint
from stereod.daemon.config_section import Section
from stereod.files.paths import TextPath


class ZenohConfig(Section):
    """The Zenoh session: key prefix, mode and endpoints (``tcp/127.0.0.1:7447``)."""

    prefix: str = Field(keys.DEFAULT_PREFIX, pattern=keys.PREFIX_PATTERN)
    mode: Literal["peer", "client", "router"] = "peer"
    connect: list[Endpoint] = Field(default_factory=list, description="Endpoints to connect to")
    listen: list[Endpoint] = Field(
        default_factory=list,
        description="Endpoints to listen on (none: a daemon on loopback only, a consumer nowhere)",
    )
    multicast_scouting: bool = Field(False, description="Find peers by multicast")
    config_file: TextPath | None = Field(
        None,
        description="A Zenoh config file (JSON5: TLS, mTLS, access control); the settings "
        "above that are given go on top of it",
    )

    @model_validator(mode="after")
    def _client_has_a_router(self) -> ZenohConfig:
        lost = self.mode == "client" and not (self.connect or self.multicast_scouting)
        if lost and self.config_file is None:  # a Zenoh file of one's own may name it
            raise ValueError(
                "mode = 'client' needs a router to connect to: give zenoh.connect (its "
                "endpoint), or multicast_scouting = true to find one"
            )
        return self
