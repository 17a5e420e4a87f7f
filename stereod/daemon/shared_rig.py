"""Two daemons publishing one rig's keys on one bus: their messages mix, and either may answer
a query. The second finds the first's liveliness token when it opens; Zenoh merges two tokens
on one key, so the first learns of the second only when the second's status comes on the rig's
status key. Each says so on its status while it lasts."""

from __future__ import annotations

import time

from stereod.daemon.status import Health

RIG_SHARED = "another stereod"
"""How the note that another daemon publishes this rig's keys begins."""
_FIX = "their messages mix and either may answer a query; give each daemon its own [rig] name"


class SharedRig:
    """Whether another daemon publishes rig ``rig``'s keys, as a notice on ``health``."""

    def __init__(self, health: Health, rig: str) -> None:
        self.health = health
        self.rig = rig
        self.said = False
        self._note = ""

    def _say(self, note: str) -> None:
        self._note = note
        self.health.problem(note, RIG_SHARED, notice=True)  # logged once, then at 10, 100...
        self.said = True

    def taken_at_open(self, base: str) -> None:
        """Another daemon's token for this rig was on the bus at open (it may be a vanished
        peer's, held until its lease ends: a running service keeps running)."""
        self._say(f"{RIG_SHARED} already publishes rig {self.rig!r} under {base}/: {_FIX}")

    def check(self, foreign_status_at: float | None, base: str, period_s: float) -> None:
        """At a status tick: say so while another daemon's statuses come on this rig's status
        key (the last at ``foreign_status_at``, monotonic s), and take it off once none came
        for three status periods (3 s at least); said again if twenty other problems pushed
        it off the status key meanwhile."""
        seen = foreign_status_at
        recent = seen is not None and time.monotonic() - seen <= max(3 * period_s, 3.0)
        if recent and not self.said:
            self._say(
                f"{RIG_SHARED} publishes rig {self.rig!r} under {base}/ too (its status came "
                f"on this rig's key): {_FIX}"
            )
        elif not recent and self.said and seen is not None:
            self.health.resolved(RIG_SHARED)
            self.said = False
        elif self.said and not self.health.showing(RIG_SHARED):
            self._say(self._note)
