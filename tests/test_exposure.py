"""Nothing listens where the user did not say: every command that opens a Zenoh session, run as
a user would, holds no socket another machine could reach (a TCP listener or a bound UDP socket
off loopback), and a consumer holds no TCP listener at all. The proof is the kernel's socket
table of the process (tests/sockets.py); nothing here connects to a non-loopback address."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import zenoh

from stereod_fakes.synth import Ball, Scene, write_scene
from tests.processes import start_stereod

from .conftest import ROOT, free_endpoint, zenoh_config
from .sockets import TCP_ESTABLISHED, Sock, exposed, process_sockets

pytestmark = pytest.mark.slow

SYNTHETIC = (
    '[driver]\nname = "synthetic"\n[driver.options]\nlive = true\nloop = true\n'
    "width_px = 160\nheight_px = 120\nfps = 15\n"
)


def wait_for(proc: subprocess.Popen, pred: Callable[[list[Sock]], bool], what: str) -> list[Sock]:
    """The process's sockets once ``pred`` holds for them (its session is open); fails with
    its stderr if it ends first or takes over a minute."""
    deadline = time.monotonic() + 60.0
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            _, err = proc.communicate(timeout=10)
            pytest.fail(f"the process ended (exit {proc.returncode}) before {what}: {err}")
        socks = process_sockets(proc.pid)
        if pred(socks):
            return socks
        time.sleep(0.05)
    pytest.fail(f"no sign that {what} after 60 s: {[str(s) for s in process_sockets(proc.pid)]}")


def listens(socks: list[Sock]) -> bool:
    return any(s.listening for s in socks)


def connected_to(port: int) -> Callable[[list[Sock]], bool]:
    return lambda socks: any(
        s.state == TCP_ESTABLISHED and s.remote_port == port for s in socks if s.proto[:3] == "tcp"
    )


@pytest.fixture
def stopped() -> Iterator[list[subprocess.Popen]]:
    """Processes to stop at the end of a test."""
    procs: list[subprocess.Popen] = []
    yield procs
    for p in procs:
        if p.poll() is None:
            p.terminate()
            try:
                p.communicate(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
                p.communicate()


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    scene = Scene(balls=[Ball(heading_deg=60, speed_mps=0.7)], duration_s=1.0)
    return write_scene(scene, tmp_path_factory.mktemp("scene") / "rec")


@pytest.fixture
def bus() -> Iterator[tuple[str, zenoh.Session]]:
    """A session on a loopback endpoint for consumers to connect to (as a daemon would)."""
    endpoint = free_endpoint()
    with zenoh.open(zenoh_config(listen=[endpoint])) as session:
        yield endpoint, session


def port_of(endpoint: str) -> int:
    return int(endpoint.rsplit(":", 1)[1])


def test_replay_without_listen_listens_on_loopback_only(
    recording: Path, stopped: list[subprocess.Popen]
) -> None:
    proc = start_stereod("replay", str(recording), "--wait-subscriber", "600")
    stopped.append(proc)
    socks = wait_for(proc, listens, "replay's session listens")
    assert not exposed(proc.pid), [str(s) for s in exposed(proc.pid)]
    assert all(s.loopback for s in socks if s.listening)


@pytest.mark.parametrize("listen", ["", "listen = []\n"], ids=["no-listen", "empty-listen"])
def test_run_without_listen_listens_on_loopback_only(
    listen: str, tmp_path: Path, stopped: list[subprocess.Popen]
) -> None:
    cfg = tmp_path / "stereod.toml"
    cfg.write_text(SYNTHETIC + f"[zenoh]\n{listen}")
    proc = start_stereod("run", "--config", str(cfg), cwd=tmp_path)
    stopped.append(proc)
    wait_for(proc, listens, "run's session listens")
    assert not exposed(proc.pid), [str(s) for s in exposed(proc.pid)]


def test_run_listens_where_told(tmp_path: Path, stopped: list[subprocess.Popen]) -> None:
    endpoint = free_endpoint()
    cfg = tmp_path / "stereod.toml"
    cfg.write_text(SYNTHETIC)
    proc = start_stereod("run", "--config", str(cfg), "--listen", endpoint, cwd=tmp_path)
    stopped.append(proc)
    socks = wait_for(proc, listens, "run's session listens")
    tcp = [(s.local, s.port) for s in socks if s.listening]
    assert tcp == [("127.0.0.1", port_of(endpoint))]


def test_subscribe_listens_nowhere(
    bus: tuple[str, zenoh.Session], stopped: list[subprocess.Popen]
) -> None:
    endpoint, _ = bus
    proc = start_stereod("subscribe", "--connect", endpoint, "--duration", "600")
    stopped.append(proc)
    socks = wait_for(proc, connected_to(port_of(endpoint)), "subscribe connects")
    assert [str(s) for s in socks if s.listening] == []


def test_client_zenoh_config_listens_nowhere(
    bus: tuple[str, zenoh.Session], stopped: list[subprocess.Popen]
) -> None:
    endpoint, _ = bus
    program = textwrap.dedent(
        f"""
        import sys, zenoh
        from stereod.client import zenoh_config
        with zenoh.open(zenoh_config({endpoint!r})):
            print("open", flush=True)
            sys.stdin.read()
        """
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", program],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )
    stopped.append(proc)
    socks = wait_for(proc, connected_to(port_of(endpoint)), "the program connects")
    assert [str(s) for s in socks if s.listening] == []


def test_view_listens_on_its_page_alone(
    bus: tuple[str, zenoh.Session], stopped: list[subprocess.Popen]
) -> None:
    """The view's web page (127.0.0.1 by default) is its one listener; its session has none."""
    endpoint, _ = bus
    proc = start_stereod("view", "--connect", endpoint, "--port", "0")
    stopped.append(proc)
    assert proc.stdout is not None
    line = proc.stdout.readline()
    assert "open http://127.0.0.1:" in line, line
    page = int(line.split("open http://127.0.0.1:", 1)[1].split("/", 1)[0])
    socks = wait_for(proc, connected_to(port_of(endpoint)), "view connects")
    assert [(s.local, s.port) for s in socks if s.listening] == [("127.0.0.1", page)]


def test_demo_listens_on_loopback_only(stopped: list[subprocess.Popen]) -> None:
    """The demo's daemon listens on 127.0.0.1; its watching session listens nowhere."""
    proc = start_stereod("demo", "--rate", "1")
    stopped.append(proc)
    socks = wait_for(proc, listens, "the demo's daemon listens")
    assert [s.local for s in socks if s.listening] == ["127.0.0.1"], [str(s) for s in socks]
