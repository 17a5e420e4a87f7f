"""``stereod view``: its server through a Zenoh router, and its page in a real headless Chromium
while a synthetic scene plays (the scene's ball is the truth: its id on the bus, its heading)."""

from __future__ import annotations

import asyncio
import json
import re
import signal
import socket
import tempfile
import threading
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import aiohttp
import cv2
import numpy as np
import pytest
import zenoh

from stereod.client import ObjectsMessage, subscribe_objects
from stereod.daemon.config import ZenohConfig, load_config
from stereod.daemon.daemon import Daemon
from stereod.daemon.status import Health
from stereod.sources.pairing import Pairer
from stereod.view.overlay import HEADER_PX
from stereod.view.server import ViewServer, browser_json
from stereod_fakes.synth import Ball, Scene, SyntheticDriver
from tests.conftest import free_endpoint, zenoh_config
from tests.processes import run_stereod, start_stereod

CHROMIUM = Path("/usr/bin/chromium")
CHROMEDRIVER = Path("/usr/bin/chromedriver")
BALL = Ball(
    heading_deg=60.0,
    speed_mps=0.4,
    centre_m=(0.0, 0.1, 2.4),
    t_on_s=1.0,
    t_mid_s=3.7,
    t_off_s=6.4,
)


def scene(duration_s: float = 7.0) -> dict[str, Any]:
    return Scene(duration_s=duration_s, fps=15.0, balls=[BALL]).model_dump(mode="json")


def daemon(zenoh_section: dict[str, Any], *, live: bool, rate: float = 1.0) -> Daemon:
    cfg = load_config(overrides={"zenoh": zenoh_section})
    return Daemon(cfg, SyntheticDriver({**scene(), "live": live}), rate=rate)


def heading_error_deg(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


def test_view_through_a_router() -> None:
    """Daemon and view on either side of a router, both in client mode: the page's socket
    carries the ball's track with its true heading, and the overlay image is served."""
    router_ep = free_endpoint()
    client = {"mode": "client", "connect": [router_ep]}
    with (
        zenoh.open(zenoh_config(listen=[router_ep], mode="router")),
        ViewServer(ZenohConfig(**client), port=0) as view,
    ):
        got: dict[str, Any] = asyncio.run(_read_socket(view, daemon(client, live=False, rate=2.0)))
    assert got["alive"] is True
    assert got["geometry"]["hfov_deg"] == pytest.approx(60.0)
    valid = got["valid"]
    assert valid, "no valid track reached the page"
    assert {o["id"] for o in valid} == {1}
    assert heading_error_deg(float(np.median([o["heading"] for o in valid])), 60.0) < 3.0
    assert got["images"], "no image announced"
    pic = cv2.imdecode(np.frombuffer(got["jpeg"], np.uint8), cv2.IMREAD_COLOR)
    assert pic.shape == (HEADER_PX + 480, 1280, 3)


async def _read_socket(view: ViewServer, d: Daemon) -> dict[str, Any]:
    got: dict[str, Any] = {"valid": [], "images": [], "alive": None, "geometry": None}
    async with aiohttp.ClientSession() as http, http.ws_connect(view.url + "ws") as ws:
        hello = json.loads((await ws.receive(timeout=10)).data)
        assert hello["type"] == "hello" and hello["rig"] == "minoru"
        thread = threading.Thread(target=d.run)
        thread.start()
        try:
            while True:
                msg = json.loads((await ws.receive(timeout=30)).data)
                if msg["type"] == "alive":
                    got["alive"] = got["alive"] or msg["alive"]
                    if not msg["alive"]:
                        break
                elif msg["type"] == "geometry":
                    got["geometry"] = msg
                elif msg["type"] == "image":
                    got["images"].append(msg)
                elif msg["type"] == "objects":
                    got["valid"] += [o for o in msg["objects"] if o["valid"]]
            async with http.get(view.url + "image/overlay.jpg") as r:
                assert r.status == 200 and r.content_type == "image/jpeg"
                got["jpeg"] = await r.read()
        finally:
            d.stop()
            await asyncio.get_running_loop().run_in_executor(None, thread.join)
    return got


# -- the page in a real browser ------------------------------------------------------------------


@pytest.fixture
def browser() -> Iterator[Any]:
    """Headless Chromium driven by chromedriver, with the console log kept."""
    missing = [str(p) for p in (CHROMIUM, CHROMEDRIVER) if not p.exists()]
    if missing:
        pytest.skip(
            f"{' and '.join(missing)} absent: apt-get install chromium chromium-driver "
            "(.ci/run does)"
        )
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    with tempfile.TemporaryDirectory(prefix="stereod-chromium-") as profile:
        options = webdriver.ChromeOptions()
        options.binary_location = str(CHROMIUM)
        for flag in (
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-dev-shm-usage",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            f"--user-data-dir={profile}",
            "--window-size=1400,1000",
        ):
            options.add_argument(flag)
        options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
        driver = webdriver.Chrome(service=Service(str(CHROMEDRIVER)), options=options)
        try:
            yield driver
        finally:
            driver.quit()


def test_page_shows_the_scene_live(browser: Any, endpoint: str, listener: zenoh.Session) -> None:
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    wait = WebDriverWait(browser, 30, poll_frequency=0.1)
    published: dict[int, ObjectsMessage] = {}
    lock = threading.Lock()

    def on_event(event: object) -> None:
        if isinstance(event, ObjectsMessage):
            with lock:
                published[event.seq] = event

    def attr(css: str, name: str) -> str | None:
        """An attribute of the first element matching ``css``, read in one go (the page
        replaces its rows as it updates)."""
        value: str | None = browser.execute_script(
            "const e = document.querySelector(arguments[0]); "
            "return e ? e.getAttribute(arguments[1]) : null;",
            css,
            name,
        )
        return value

    with (
        ViewServer(ZenohConfig(connect=[endpoint]), port=0) as view,
        subscribe_objects(listener, on_event),
    ):
        browser.get(view.url)
        wait.until(lambda b: b.find_element(By.ID, "server").text == "page: connected")
        first = daemon({"connect": [endpoint]}, live=True)
        thread = threading.Thread(target=first.run)
        thread.start()
        try:
            wait.until(lambda b: b.find_element(By.ID, "daemon").text == "daemon: running")
            # The ball's track appears with a valid velocity: its id is the one on the bus, its
            # heading the scene's.
            row = 'tr[data-valid="true"]'
            wait.until(lambda b: attr(row, "data-heading-deg") is not None)
            headings = []
            for _ in range(16):  # successive readings as the page updates
                seen = attr(row, "data-heading-deg")
                wait.until(lambda b, seen=seen: attr(row, "data-heading-deg") != seen)
                headings.append(float(attr(row, "data-heading-deg") or "nan"))
            track_id = int(attr(row, "data-track-id") or -1)
            # The overlay image updates, and each one is a pair that was published.
            wait.until(lambda b: attr("#overlay", "data-seq"))
            seq1 = int(attr("#overlay", "data-seq") or -1)
            wait.until(lambda b: attr("#overlay", "data-seq") not in ("", str(seq1)))
            seq2 = int(attr("#overlay", "data-seq") or -1)
            natural = browser.execute_script(
                "const i = document.getElementById('overlay'); return [i.naturalWidth, "
                "i.naturalHeight];"
            )
        finally:
            thread.join()
        # The daemon went away: the page says so, then a new one is seen coming back.
        wait.until(lambda b: b.find_element(By.ID, "daemon").text == "daemon: gone")
        second = daemon({"connect": [endpoint]}, live=True)
        thread = threading.Thread(target=second.run)
        thread.start()
        try:
            wait.until(lambda b: b.find_element(By.ID, "daemon").text == "daemon: running")
            wait.until(lambda b: attr('tr[data-state="confirmed"]', "data-track-id") is not None)
        finally:
            second.stop()
            thread.join()
        logs = browser.get_log("browser")
    with lock:
        ids = {o.track_id for m in published.values() for o in m.objects if o.velocity_valid}
        seqs = set(published)
    assert ids == {track_id} == {1}, (ids, track_id)
    # The page shows the filter's heading as it settles: after its first readings their median
    # is the scene's to 2 deg, and none is off by the paper's 5 deg plus a reading's jitter
    # when the browser and a live daemon share two cores (single readings are scored
    # offline, against both renderers, in tests/test_accuracy.py).
    settled = [heading_error_deg(h, BALL.heading_deg) for h in headings[8:]]
    assert float(np.median(settled)) < 2.0, headings
    assert max(settled) < 8.0, headings
    assert seq2 != seq1 and {seq1, seq2} <= seqs
    assert natural == [1280, HEADER_PX + 480]
    errors = [e for e in logs if e["level"] == "SEVERE"]
    assert errors == [], errors


def test_view_command_prints_its_url_and_stops_on_sigint(endpoint: str) -> None:
    proc = start_stereod("view", "--port", "0", "--connect", endpoint)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        url = re.search(r"open (http://127\.0\.0\.1:\d+/) ", line)
        assert url, line
        assert f"Zenoh peer, to {endpoint})" in line
        with urllib.request.urlopen(url.group(1), timeout=10) as r:
            page = r.read().decode()
        assert '<canvas id="map"' in page and "/static/view.js" in page
        # The same port again is in use: one line, exit 69 (unavailable, as a Zenoh
        # endpoint in use is), naming the flag that picks another.
        port = url.group(1).rsplit(":", 1)[1].strip("/")
        busy = run_stereod("view", "--port", port, "--connect", endpoint, timeout=60)
        assert busy.returncode == 69, busy.stderr
        assert busy.stderr.count("\n") == 1 and f"127.0.0.1:{port}" in busy.stderr
        assert "pick another port with --port, or --port 0" in busy.stderr
        # A host that is not this machine's: the host is at fault, not the port.
        alien = run_stereod("view", "--host", "999.1.1.1", "--connect", endpoint, timeout=60)
        assert alien.returncode == 64, alien.stderr  # a flag's bad value
        assert alien.stderr.count("\n") == 1 and "check --host" in alien.stderr
    finally:
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err


def raw_request(port: int, path: str, headers: dict[str, str]) -> str:
    """The status line of one HTTP/1.1 request sent as raw bytes to 127.0.0.1:``port`` (so
    Host and Origin are exactly what a rebinding page's browser would send)."""
    lines = [f"GET {path} HTTP/1.1", *(f"{k}: {v}" for k, v in headers.items()), "", ""]
    with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
        s.sendall("\r\n".join(lines).encode())
        reply = b""
        while b"\r\n" not in reply:
            chunk = s.recv(4096)
            if not chunk:
                break
            reply += chunk
    return reply.split(b"\r\n", 1)[0].decode()


UPGRADE = {
    "Upgrade": "websocket",
    "Connection": "Upgrade",
    "Sec-WebSocket-Key": "dGhlIHNhbXBsZSBub25jZQ==",
    "Sec-WebSocket-Version": "13",
}


def test_page_and_socket_refuse_another_sites_host_and_origin(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """DNS rebinding: a page of evil.example whose name now resolves to 127.0.0.1 sends Host
    evil.example and Origin http://evil.example; the view refuses both (403, no WebSocket
    upgrade) and says so once, and still serves its own address and localhost names."""
    with ViewServer(ZenohConfig(), port=0) as server:
        port = server.port
        own = f"127.0.0.1:{port}"
        assert raw_request(port, "/", {"Host": own}).endswith("200 OK")
        for name in ("localhost", "[::1]", "LOCALHOST"):
            assert raw_request(port, "/", {"Host": f"{name}:{port}"}).endswith("200 OK")
        ws_ok = raw_request(port, "/ws", {"Host": own, "Origin": f"http://{own}", **UPGRADE})
        assert " 101 " in ws_ok, ws_ok
        caplog.clear()
        refused = [
            ("/", {"Host": f"evil.example:{port}"}),
            ("/", {"Host": "evil.example"}),
            ("/", {"Host": f"127.0.0.1:{port + 1}"}),
            ("/image/overlay.jpg", {"Host": f"evil.example:{port}"}),
            ("/", {"Host": own, "Origin": "http://evil.example"}),
            ("/ws", {"Host": f"evil.example:{port}", "Origin": "http://evil.example", **UPGRADE}),
            ("/ws", {"Host": own, "Origin": "http://evil.example", **UPGRADE}),
            ("/ws", {"Host": own, "Origin": f"http://evil.example:{port}", **UPGRADE}),
            ("/ws", {"Host": own, "Origin": "null", **UPGRADE}),
        ]
        for path, headers in refused:
            status = raw_request(port, path, headers)
            assert status.endswith("403 Forbidden"), (path, headers, status)
        assert server.refused == len(refused)
    said = [r for r in caplog.records if "refused a request" in r.getMessage()]
    assert len(said) == 1, [r.getMessage() for r in caplog.records]
    assert "evil.example" in said[0].getMessage()


def test_a_status_with_a_nan_reaches_the_page_as_json_it_can_parse(
    endpoint: str, listener: zenoh.Session
) -> None:
    """A status carrying a NaN (pydantic takes it) went to the page as a bare ``NaN`` token,
    which ``JSON.parse`` refuses: that update was dropped, and every page opened after it
    stayed blank. Through a real view server and its socket, a strict parser now reads the
    update and a later page's hello, the NaN as null."""
    health = Health("minoru", "test", Pairer(), on_change=lambda: None)
    raw = json.loads(health.status().model_dump_json(by_alias=True))
    payload = json.dumps({**raw, "uptime_s": float("nan")}).encode()  # Python writes NaN

    def strict(text: str) -> Any:
        return json.loads(text, parse_constant=lambda c: pytest.fail(f"{c} in {text[:80]}"))

    async def pages(view: ViewServer) -> tuple[Any, Any]:
        async with aiohttp.ClientSession() as http:
            async with http.ws_connect(view.url + "ws") as ws:
                strict((await ws.receive(timeout=10)).data)  # hello
                deadline = time.monotonic() + 15.0
                while True:  # (put again until the view's subscription routes it)
                    listener.put("stereod/minoru/status", payload)
                    try:
                        update = strict((await ws.receive(timeout=0.5)).data)
                    except TimeoutError:
                        assert time.monotonic() < deadline, "no status reached the page"
                        continue
                    if update["type"] == "status":
                        break
            async with http.ws_connect(view.url + "ws") as ws:
                return update, strict((await ws.receive(timeout=10)).data)

    with ViewServer(ZenohConfig(connect=[endpoint]), port=0) as view:
        update, hello = asyncio.run(pages(view))
    assert update["status"]["uptime_s"] is None and hello["status"]["uptime_s"] is None
    assert strict(browser_json({"a": [1.5, float("inf")], "b": {"c": -float("inf")}})) == {
        "a": [1.5, None],
        "b": {"c": None},
    }
