"""A daemon's status says how its host's clock is disciplined: chrony's tracking or linuxptp's
time status where readable, else unknown. The tools' outputs here are the formats their
manuals print; where neither tool is installed, the real lookup gives ``unknown``."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from stereod.fusion.discipline import parse_chrony, parse_pmc, read_discipline

# `chronyc -c tracking` as chrony's manual shows it (fields: ref id, name, stratum, ref time,
# system time offset, last offset, RMS offset, freq, residual freq, skew, root delay, root
# dispersion, update interval, leap status).
CHRONY = (
    "A29FC87B,ntp1.example.net,3,1446390466.591063442,-0.000009279,-0.000011012,"
    "0.000070126,-8.587,-0.001,0.039,0.013914286,0.000717637,64.9,Normal\n"
)
PMC = """sending: GET TIME_STATUS_NP
\t90e2ba.fffe.0a1b2c-0 seq 0 RESPONSE MANAGEMENT TIME_STATUS_NP
\t\tmaster_offset              -412
\t\tingress_time               1446390466591063442
\t\tcumulativeScaledRateOffset +0.000000000
\t\tgmPresent                  true
\t\tgmIdentity                 001122.fffe.334455
"""


def test_chrony_tracking_is_read_field_by_field() -> None:
    d = parse_chrony(CHRONY)
    assert d is not None and d.source == "chrony" and d.synchronised is True
    assert d.offset_s == pytest.approx(-9.279e-6) and d.state == "Normal"
    assert d.reference == "ntp1.example.net"
    lost = parse_chrony(CHRONY.replace("Normal", "Not synchronised"))
    assert lost is not None and lost.synchronised is False
    assert parse_chrony("506 Cannot talk to daemon") is None


def test_ptp_time_status_is_read() -> None:
    d = parse_pmc(PMC)
    assert d is not None and d.source == "ptp" and d.synchronised is True
    assert d.offset_s == pytest.approx(-412e-9) and d.reference == "001122.fffe.334455"
    assert parse_pmc("sending: GET TIME_STATUS_NP\n") is None


def tool(folder: Path, name: str, output: str, code: int = 0) -> None:
    path = folder / name
    path.write_text(f"#!/bin/sh\ncat <<'END'\n{output}END\nexit {code}\n")
    path.chmod(path.stat().st_mode | stat.S_IXUSR)


def test_the_host_is_asked_chrony_first_then_ptp_else_unknown(tmp_path: Path) -> None:
    """Executables on the search path stand for the tools (neither is installed here)."""
    empty = tmp_path / "none"
    empty.mkdir()
    assert read_discipline(str(empty)).source == "unknown"
    ptp = tmp_path / "ptp"
    ptp.mkdir()
    tool(ptp, "pmc", PMC)
    tool(ptp, "chronyc", "506 Cannot talk to daemon\n", code=1)
    assert read_discipline(str(ptp)).source == "ptp"
    both = tmp_path / "both"
    both.mkdir()
    tool(both, "pmc", PMC)
    tool(both, "chronyc", CHRONY)
    assert read_discipline(str(both)).source == "chrony"
    assert os.access(both / "chronyc", os.X_OK)


def test_the_daemon_status_carries_the_clock_discipline() -> None:
    """The status key's message has the field (unknown here: no chrony, no PTP on this host's
    PATH unless installed, then whichever answers)."""
    from stereod.bus.messages import StatusMessage
    from stereod.daemon.status import Health
    from stereod.sources.pairing import Pairer

    h = Health("bench", "test", Pairer(), on_change=lambda: None)
    status = StatusMessage.model_validate_json(h.status().model_dump_json(by_alias=True))
    assert status.clock is not None
    assert status.clock == read_discipline() or status.clock.source == "unknown"
