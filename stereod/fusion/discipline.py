"""How this host's clock is kept on UTC, for a daemon's status key: chrony's tracking
(``chronyc -c tracking``) or linuxptp's time status (``pmc -u -b 0 'GET TIME_STATUS_NP'``)
where one of them is installed and answers, else ``unknown``.

Rigs fused in one room stamp their objects with their own host's UTC clock
(``stamp_utc_ns``); a person walking at 1.5 m/s moves 1.5 cm per 10 ms of clock error, so a
fusion node wants to know how each rig's clock is held. Asking is a subprocess of a few
milliseconds, so the answer is kept for :data:`CACHE_S`.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import threading
import time

from stereod.bus.messages import ClockDiscipline

CACHE_S = 30.0
"""How long one reading is reused, s."""
TIMEOUT_S = 1.0
"""How long a tool may take to answer, s."""

UNKNOWN = ClockDiscipline(source="unknown")


def parse_chrony(line: str) -> ClockDiscipline | None:
    """``chronyc -c tracking``'s CSV line: reference id, name, stratum, reference time, system
    time offset (s), last offset, RMS offset, frequency, residual frequency, skew, root delay,
    root dispersion, update interval, leap status. None when it is not such a line."""
    f = line.strip().split(",")
    if len(f) < 14:
        return None
    try:
        offset = float(f[4])
    except ValueError:
        return None
    leap = f[13]
    return ClockDiscipline(
        source="chrony",
        synchronised=leap != "Not synchronised" and f[0] != "00000000",
        offset_s=offset,
        state=leap,
        reference=f[1] or None,
    )


def parse_pmc(text: str) -> ClockDiscipline | None:
    """``pmc``'s TIME_STATUS_NP reply: ``master_offset`` (ns), ``gmPresent``, ``gmIdentity``.
    None when the reply has no master offset."""
    values: dict[str, str] = {}
    for line in text.splitlines():
        parts = line.split()
        if len(parts) == 2:
            values[parts[0]] = parts[1]
    try:
        offset_ns = int(values["master_offset"])
    except (KeyError, ValueError):
        return None
    present = values.get("gmPresent")
    return ClockDiscipline(
        source="ptp",
        synchronised=None if present is None else present == "true",
        offset_s=offset_ns * 1e-9,
        state="gm present" if present == "true" else "no grandmaster",
        reference=values.get("gmIdentity"),
    )


def _run(argv: list[str], path: str | None) -> str | None:
    exe = shutil.which(argv[0], path=path)
    if exe is None:
        return None
    try:
        res = subprocess.run(
            [exe, *argv[1:]],
            capture_output=True,
            text=True,
            timeout=TIMEOUT_S,
            check=False,
            env={**os.environ, "LC_ALL": "C"},
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return res.stdout if res.returncode == 0 else None


def read_discipline(path: str | None = None) -> ClockDiscipline:
    """This host's clock discipline now (``path``: where to look for the tools, default
    ``PATH``): chrony first, then PTP, else ``unknown``."""
    out = _run(["chronyc", "-c", "tracking"], path)
    found = parse_chrony(out.splitlines()[0]) if out else None
    if found is not None:
        return found
    out = _run(["pmc", "-u", "-b", "0", "GET TIME_STATUS_NP"], path)
    found = parse_pmc(out) if out else None
    return found if found is not None else UNKNOWN


class DisciplineCache:
    """:func:`read_discipline`, asked again at most every :data:`CACHE_S` seconds, in the
    background so that a status period never waits on a tool."""

    def __init__(self) -> None:
        self._value = UNKNOWN
        self._at: float | None = None
        self._busy = threading.Lock()

    def get(self) -> ClockDiscipline:
        """The latest reading (``unknown`` before the first), starting a new one when due."""
        now = time.monotonic()
        if (self._at is None or now - self._at >= CACHE_S) and self._busy.acquire(False):
            self._at = now
            threading.Thread(target=self._refresh, name="clock", daemon=True).start()
        return self._value

    def _refresh(self) -> None:
        try:
            self._value = read_discipline()
        finally:
            self._busy.release()
