"""Beyond one machine: the daemon and a subscriber as clients of a Zenoh router; traffic
survives the router being killed and started again."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest
import zenoh

from stereod_fakes.synth import Scene, write_scene
from tests.processes import stereod_command

from .conftest import ROOT, free_endpoint, zenoh_config

pytestmark = pytest.mark.slow

ROUTER = """
import json, signal, sys, threading, zenoh
cfg = zenoh.Config()
cfg.insert_json5("mode", '"router"')
cfg.insert_json5("scouting", '{"delay": 0, "multicast": {"enabled": false}}')
cfg.insert_json5("listen/endpoints", json.dumps([sys.argv[1]]))
done = threading.Event()
signal.signal(signal.SIGTERM, lambda *_: done.set())
with zenoh.open(cfg):
    print("up", flush=True)
    done.wait()
"""


def start_router(endpoint: str, **popen: Any) -> subprocess.Popen[str]:
    """A Zenoh router listening on ``endpoint``, up when this returns (``popen``: more
    :class:`subprocess.Popen` arguments, for example a ``preexec_fn``)."""
    proc = subprocess.Popen(
        [sys.executable, "-c", ROUTER, endpoint],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        **popen,
    )
    assert proc.stdout is not None and proc.stdout.readline().strip() == "up"
    return proc


def test_messages_flow_through_a_router_and_resume_after_it_restarts(tmp_path: Path) -> None:
    rec = write_scene(Scene(duration_s=2.0, fps=15), tmp_path / "rec")
    endpoint = free_endpoint()
    router = start_router(endpoint)
    daemon = subprocess.Popen(
        stereod_command(
            "replay",
            str(rec),
            "--loop",
            "--rate",
            "1",
            "--mode",
            "client",
            "--connect",
            endpoint,
            "-q",
        ),
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    seqs: list[float] = []
    lock = threading.Lock()

    def on(sample: zenoh.Sample) -> None:
        with lock:
            seqs.append(time.monotonic())

    def arrivals_after(t: float) -> int:
        with lock:
            return sum(1 for s in seqs if s > t)

    def wait_arrivals(after: float, n: int, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if arrivals_after(after) >= n:
                return True
            time.sleep(0.05)
        return False

    try:
        with zenoh.open(zenoh_config(connect=[endpoint], mode="client")) as session:
            sub = session.declare_subscriber("stereod/minoru/objects", on)
            t0 = time.monotonic()
            assert wait_arrivals(t0, 10, 20), "no messages through the router"
            router.send_signal(signal.SIGKILL)
            router.communicate(timeout=10)
            time.sleep(1.0)
            assert daemon.poll() is None, "the daemon must survive losing the router"
            router = start_router(endpoint)
            t1 = time.monotonic()
            assert wait_arrivals(t1, 10, 30), "messages did not resume after the router restarted"
            sub.undeclare()
    finally:
        daemon.send_signal(signal.SIGTERM)
        try:
            _, err = daemon.communicate(timeout=15)
        finally:
            daemon.kill()
            router.send_signal(signal.SIGTERM)
            router.communicate(timeout=10)
    assert daemon.returncode == 0, err


def test_killed_subscriber_does_not_disturb_the_daemon(tmp_path: Path) -> None:
    """A subscriber process killed mid-stream: the daemon keeps publishing every message to the
    subscribers that remain."""
    rec = write_scene(Scene(duration_s=3.0, fps=15), tmp_path / "rec")
    endpoint = free_endpoint()
    received: list[int] = []
    with zenoh.open(zenoh_config(listen=[endpoint])) as session:
        sub = session.declare_subscriber(
            "stereod/minoru/objects",
            lambda s: received.append(json.loads(s.payload.to_bytes())["seq"]),
        )
        victim = subprocess.Popen(
            stereod_command("subscribe", "--connect", endpoint, "--json"),
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        daemon = subprocess.Popen(
            stereod_command(
                "replay",
                str(rec),
                "--rate",
                "1",
                "--connect",
                endpoint,
                "--wait-subscriber",
                "10",
            ),
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        time.sleep(1.5)
        victim.kill()
        victim.communicate(timeout=10)
        out, err = daemon.communicate(timeout=60)
        time.sleep(0.3)
        sub.undeclare()
    assert daemon.returncode == 0, err
    assert "45 pairs" in out
    assert sorted(received) == list(range(45)), "a message was lost after the subscriber died"
