"""sd_notify against real datagram sockets, and a real `stereod run` driven like systemd does."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh

from stereod.daemon.sdnotify import Notifier
from stereod.vision.calibration import canonical, save

from .conftest import ROOT, zenoh_config
from .processes import collect, receiver

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("abstract", [False, True])
def test_notifier_reaches_path_and_abstract_sockets(tmp_path: Path, abstract: bool) -> None:
    sock, address = receiver(tmp_path, abstract)
    sock.settimeout(2)
    n = Notifier({"NOTIFY_SOCKET": address, "WATCHDOG_USEC": "3000000"})
    assert n.enabled and n.watchdog_s == 3.0
    assert n.notify(READY=1, STATUS="two\nlines")
    assert sock.recv(4096) == b"READY=1\nSTATUS=two lines"
    n.close()
    sock.close()


def test_no_socket_no_op() -> None:
    n = Notifier({})
    assert not n.enabled and n.watchdog_s is None and n.notify(READY=1) is False
    assert Notifier({"WATCHDOG_USEC": "100", "WATCHDOG_PID": "1"}).watchdog_s is None


def write_config(
    path: Path, endpoint: str, threshold: float, calibration: Path | None = None
) -> None:
    cal = f'calibration = "{calibration}"\n' if calibration else ""
    path.write_text(
        f'[rig]\nname = "svc"\n{cal}'
        '[driver]\nname = "synthetic"\n[driver.options]\nlive = true\nduration_s = 30.0\n'
        f"fps = 15\n[detector]\nthreshold = {threshold}\n"
        f'[zenoh]\nlisten = ["{endpoint}"]\n[daemon]\nstatus_period_s = 0.5\n'
    )


def test_run_speaks_the_notify_protocol_in_order(tmp_path: Path, endpoint: str) -> None:
    sock, address = receiver(tmp_path)
    cfg = tmp_path / "svc.toml"
    write_config(cfg, endpoint, 25.0)
    env = {**os.environ, "NOTIFY_SOCKET": address, "WATCHDOG_USEC": "1000000"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "stereod._entry", "run", "--config", str(cfg)],
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        first = collect(sock, "READY=1", 30)
        assert "READY=1" in first, first
        running = collect(sock, "no such line", 2.0)
        assert "WATCHDOG=1" in running, running
        assert any(line.startswith("STATUS=running: left") for line in first + running)
        write_config(cfg, endpoint, 30.0)
        proc.send_signal(signal.SIGHUP)
        reload = collect(sock, "READY=1", 10)
        assert reload.index("RELOADING=1") < reload.index("READY=1"), reload
        t0 = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=10)
        stop_s = time.monotonic() - t0
        tail = collect(sock, "STOPPING=1", 1)
    finally:
        proc.kill()
        sock.close()
    assert proc.returncode == 0, err
    assert "STOPPING=1" in tail
    assert stop_s < 2.0, f"SIGTERM took {stop_s:.2f} s"
    assert "configuration reloaded" in err
    assert "Traceback" not in err


def test_garbage_calibration_on_reload_keeps_the_old_one(tmp_path: Path, endpoint: str) -> None:
    cal = canonical(0.06, 60.0, 640, 480)
    cal_path = tmp_path / "cal.json"
    save(cal, cal_path)
    cfg = tmp_path / "svc.toml"
    write_config(cfg, endpoint, 25.0, cal_path)
    proc = subprocess.Popen(
        [sys.executable, "-m", "stereod._entry", "run", "--config", str(cfg)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    statuses: list[dict] = []
    try:
        with zenoh.open(zenoh_config(connect=[endpoint])) as s:
            sub = s.declare_subscriber(
                "stereod/svc/status",
                lambda smp: statuses.append(json.loads(smp.payload.to_bytes())),
            )
            deadline = time.monotonic() + 30
            while (
                not any(st["state"] == "running" for st in statuses) and time.monotonic() < deadline
            ):
                time.sleep(0.05)
            assert statuses and statuses[-1]["calibration_id"] == cal.id
            cal_path.write_text("garbage, not JSON")
            proc.send_signal(signal.SIGHUP)
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline and not any(
                "reload refused" in p for st in statuses for p in st["problems"]
            ):
                time.sleep(0.05)
            sub.undeclare()
        assert proc.poll() is None, "the daemon must keep running"
    finally:
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=10)
    problems = [p for st in statuses for p in st["problems"] if "reload refused" in p]
    assert (
        problems
        and "cal.json" in problems[0]
        and "keeping the running configuration" in problems[0]
    )
    assert statuses[-1]["calibration_id"] == cal.id
    assert proc.returncode == 0, err


def test_a_run_killed_by_the_watchdog_leaves_every_thread_stack_in_the_journal(
    tmp_path: Path, endpoint: str
) -> None:
    """systemd's watchdog ends a hung daemon with SIGABRT: its stderr (the journal) then
    holds each thread's Python stack, the pipeline thread's loop among them, to say where
    it hung."""
    sock, address = receiver(tmp_path)
    cfg = tmp_path / "svc.toml"
    write_config(cfg, endpoint, 25.0)
    env = {**os.environ, "NOTIFY_SOCKET": address}
    proc = subprocess.Popen(
        [sys.executable, "-m", "stereod._entry", "run", "--config", str(cfg)],
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert "READY=1" in collect(sock, "READY=1", 30)
        proc.send_signal(signal.SIGABRT)
        _, err = proc.communicate(timeout=20)
    finally:
        proc.kill()
        sock.close()
    assert proc.returncode == -signal.SIGABRT
    assert "Fatal Python error: Aborted" in err, err[-2000:]
    assert "stereod/daemon/processing.py" in err and "in loop" in err, err[-2000:]
