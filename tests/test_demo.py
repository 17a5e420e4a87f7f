"""The demo end to end (as fast as possible): it must report the truth it rendered."""

from __future__ import annotations

import asyncio
import contextlib
import json
import re
import signal
import socket
import subprocess
import urllib.request
from pathlib import Path

import aiohttp
import pytest

from stereod.tracking.motion import angle_diff_deg
from stereod.view.demo import (
    DEMO_PORT,
    DemoBall,
    demo_config,
    free_tcp_port,
    listening_session,
    run_demo,
)
from stereod_fakes.synth import Scene, scene_from_truth
from tests.processes import run_stereod, start_stereod


def test_angle_difference_wraps() -> None:
    assert angle_diff_deg(359.0, 1.0) == pytest.approx(-2.0)
    assert angle_diff_deg(1.0, 359.0) == pytest.approx(2.0)
    assert angle_diff_deg(180.0, 0.0) == pytest.approx(180.0)


@pytest.mark.slow
def test_demo_measures_heading_and_speed(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """With its usual port taken, the demo says where it listens instead, and still works.
    ``--keep DIR`` keeps the recording with the scene's truth (it kept no truth.json, so
    ``plot --truth DIR/truth.json`` failed)."""
    with socket.socket() as taken:
        taken.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # past any TIME_WAIT
        with contextlib.suppress(OSError):  # already taken by someone else: as good
            taken.bind(("127.0.0.1", DEMO_PORT))
            taken.listen()
        assert run_demo(rate=0.0, heading_deg=210.0, speed_mps=0.7, keep=tmp_path / "kept") == 0
    out = capsys.readouterr().out
    scene = scene_from_truth(tmp_path / "kept" / "truth.json")
    assert scene == Scene.model_validate(DemoBall(210.0, 0.7).scene_options())
    assert f"zenoh: port {DEMO_PORT} is taken, listening on tcp/127.0.0.1:" in out
    assert "within the paper's errors" in out
    error_line = next(line for line in out.splitlines() if line.startswith("error"))
    dh, ds = (float(v) for v in error_line.split()[1:])
    assert abs(dh) < 1.0 and abs(ds) < 0.02, error_line


@pytest.mark.slow
def test_demo_with_view_plays_once_a_page_is_open_and_serves_it_after() -> None:
    """``stereod demo --view``: the scene waits for a page; the page (a WebSocket client here)
    gets the ball's track with its true heading; the numbers are printed; the page stays up
    until Ctrl-C, which ends the demo with the numbers' verdict."""
    proc = start_stereod("demo", "--view", "--view-port", "0", "--rate", "2", "--heading", "120")
    assert proc.stdout is not None
    try:
        lines = [proc.stdout.readline() for _ in range(2)]
        if lines[1].startswith("zenoh: port"):  # 7447 is taken on this machine
            lines.append(proc.stdout.readline())
        url = re.search(r"view: open (http://127\.0\.0\.1:\d+/) ", lines[-1])
        assert url, lines
        try:
            headings = asyncio.run(_page_headings(url.group(1)))
        except ConnectionError as exc:  # the view went away: the demo says why on stderr
            proc.send_signal(signal.SIGINT)
            _, err = proc.communicate(timeout=30)
            raise AssertionError(f"{exc}; the demo exited {proc.returncode}: {err}") from exc
        rest = []
        for line in proc.stdout:
            rest.append(line)
            if line.startswith("view: the page stays"):
                break
        # The page is still served after the numbers.
        with urllib.request.urlopen(url.group(1), timeout=10) as r:
            assert r.status == 200
    finally:
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    assert any("within the paper's errors" in line for line in rest), rest
    assert headings and all(abs(angle_diff_deg(h, 120.0)) < 5.0 for h in headings[-5:]), headings


@pytest.mark.slow
def test_ctrl_c_while_the_demo_plays_stops_it_cleanly(tmp_path: Path) -> None:
    """Ctrl-C mid-scene: every thread of the daemon ends (the images thread too), the scene's
    folder is removed, and the exit is 130 with no traceback."""
    _stopped_cleanly(tmp_path, ["--rate", "1"], "t ", signal.SIGINT)  # "t ": a track


def test_sigterm_while_the_view_waits_for_a_page_removes_the_scene(tmp_path: Path) -> None:
    """``timeout`` or ``kill`` while ``demo --view`` waits for a page: the demo ends as
    interrupted (exit 143, its line, no traceback) and its scene's temporary folder is gone."""
    err = _stopped_cleanly(
        tmp_path, ["--view", "--view-port", "0"], "view: open", signal.SIGTERM, 143
    )
    assert err.splitlines() == ["stereod: demo interrupted by SIGTERM"]


@pytest.mark.parametrize(("sig", "code"), [(signal.SIGTERM, 143), (signal.SIGHUP, 129)])
def test_sigterm_or_sighup_while_the_demo_plays_ends_it_as_interrupted(
    tmp_path: Path, sig: signal.Signals, code: int
) -> None:
    """SIGTERM or SIGHUP mid-scene stops the daemon cleanly and exits 128 plus the signal,
    with one line naming it (it exited 130, as on Ctrl-C, and said nothing)."""
    err = _stopped_cleanly(tmp_path, ["--rate", "1"], "t ", sig, code)
    assert err.splitlines() == [f"stereod: demo interrupted by {sig.name}"]


def _stopped_cleanly(
    tmp_path: Path, flags: list[str], until: str, sig: signal.Signals, code: int = 130
) -> str:
    """Start ``stereod demo`` with ``flags`` (its temporary folder under ``tmp_path``), send
    ``sig`` once a line starts with ``until``, and check it ended cleanly: exit ``code``, no
    traceback, its scene's folder gone; its stderr."""
    proc = start_stereod("demo", *flags, env={"TMPDIR": str(tmp_path)})
    assert proc.stdout is not None
    try:
        line = ""
        while not line.startswith(until):
            line = proc.stdout.readline()
            assert line, f"the demo ended before a line starting {until!r}"
        assert list(tmp_path.glob("stereod-demo-*"))
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == code, err
    assert "Traceback" not in err
    assert not list(tmp_path.glob("stereod-demo-*"))
    return err


def test_a_reader_that_stops_reading_ends_the_demo_quietly() -> None:
    """``stereod demo | head -2``: the demo stops its daemon and exits 0, saying nothing."""
    proc = start_stereod("demo", "--rate", "0", stdout=subprocess.PIPE)
    assert proc.stdout is not None and proc.stderr is not None
    first = [proc.stdout.readline() for _ in range(2)]
    if first[1].startswith("zenoh: port"):  # 7447 is taken on this machine
        first[1] = proc.stdout.readline()
    proc.stdout.close()  # the reader is gone
    with proc.stderr:
        err = proc.stderr.read()
    assert proc.wait(timeout=60) == 0, err
    assert first[1].startswith("t ") and err == ""


async def _page_headings(url: str) -> list[float]:
    """Valid headings of the messages a page receives until the daemon goes away."""
    headings: list[float] = []
    async with aiohttp.ClientSession() as http, http.ws_connect(url + "ws") as ws:
        while True:
            frame = await ws.receive(timeout=60)
            if frame.type != aiohttp.WSMsgType.TEXT:
                raise ConnectionError(f"the page got {frame.type.name} {frame.data} first")
            msg = json.loads(frame.data)
            if msg["type"] == "objects":
                headings += [o["heading"] for o in msg["objects"] if o["valid"]]
            elif msg["type"] == "alive" and not msg["alive"]:
                return headings


def test_a_port_left_in_time_wait_is_free_for_the_demo() -> None:
    """After a demo, its port's last connections linger in TIME_WAIT for a minute; a server
    (the demo's Zenoh) may listen there, so the demo must not move to another port."""
    with socket.socket() as server:
        server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        server.bind(("127.0.0.1", 0))
        server.listen()
        port = server.getsockname()[1]
        client = socket.create_connection(("127.0.0.1", port))
        conn, _ = server.accept()
        conn.close()  # the server side closes first: it keeps the TIME_WAIT
        client.close()
    with listening_session(port) as listening:
        assert listening.endpoint == f"tcp/127.0.0.1:{port}"


def test_the_demo_holds_its_port_from_the_start(capsys: pytest.CaptureFixture[str]) -> None:
    """Two demos started together cannot both take a port: the demo listens from the moment
    it picks its port (not once a page opens), so the second finds it taken and moves on,
    saying where it went."""
    with listening_session(free_tcp_port()) as first:
        port = int(first.endpoint.rsplit(":", 1)[1])
        with socket.socket() as other, pytest.raises(OSError):  # another program: refused
            other.bind(("127.0.0.1", port))
        with listening_session(port) as second:
            assert second.endpoint != first.endpoint
    assert (
        f"zenoh: port {port} is taken, listening on {second.endpoint} " in capsys.readouterr().out
    )


def test_demo_view_on_a_port_in_use_names_its_own_flag(tmp_path: Path) -> None:
    """``stereod demo --view`` on a port another program serves: one line naming the flag the
    demo has (``--view-port``, not view's ``--port``), exit 69 (unavailable, as a Zenoh
    endpoint in use is: a busy port is no configuration error), the scene's folder gone."""
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        res = run_stereod("demo", "--view", "--view-port", str(port), env={"TMPDIR": str(tmp_path)})
    lines = res.stderr.splitlines()
    assert res.returncode == 69, res.stderr
    assert len(lines) == 1 and f"127.0.0.1:{port}" in lines[0], res.stderr
    assert "pick another port with --view-port, or --view-port 0" in lines[0]
    assert "with --port" not in lines[0]
    assert not list(tmp_path.glob("stereod-demo-*"))


def test_the_demo_s_config_queryable_names_the_replay_it_runs(tmp_path: Path) -> None:
    """The configuration the demo's daemon runs and reports on its ``config`` key is the
    replay of its scene (it reported the camera driver of the defaults, with no options, while
    its status said replay)."""
    from stereod.daemon.redact import public_config

    cfg = demo_config("tcp/127.0.0.1:17447", tmp_path / "scene")
    public = public_config(cfg)
    assert public["driver"]["name"] == "replay"
    assert public["driver"]["options"]["path"] == "scene"  # a path reduced to its name
    assert public["zenoh"]["listen"] == ["tcp/127.0.0.1:17447"]
