"""Take the README's screenshot of ``stereod view`` (docs/view.png): a synthetic ball crossing
the room, played live by the daemon, watched in headless Chromium.

Usage: ``.venv/bin/python docs/screenshot.py [OUT.png]`` (needs Debian's chromium and
chromium-driver, and selenium from the dev extra).
"""

from __future__ import annotations

import io
import socket
import sys
import tempfile
import threading
import time
from pathlib import Path

from PIL import Image
from selenium import webdriver
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.support.ui import WebDriverWait

from stereod.daemon.config import ZenohConfig, load_config
from stereod.daemon.daemon import Daemon
from stereod.view.server import ViewServer
from stereod_fakes.synth import Ball, Scene, SyntheticDriver


def main() -> None:
    out = Path(sys.argv[1] if len(sys.argv) > 1 else "docs/view.png")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        endpoint = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    ball = Ball(
        heading_deg=60.0,
        speed_mps=0.4,
        centre_m=(0.0, 0.1, 2.4),
        t_on_s=1.0,
        t_mid_s=3.7,
        t_off_s=6.4,
    )
    scene = Scene(duration_s=7.0, fps=15.0, balls=[ball], drift=0.02)
    cfg = load_config(overrides={"zenoh": {"listen": [endpoint]}})
    opts = webdriver.ChromeOptions()
    opts.binary_location = "/usr/bin/chromium"
    with tempfile.TemporaryDirectory() as profile:
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
            "--window-size=1280,1000",
        ):
            opts.add_argument(flag)
        browser = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=opts)
        daemon = Daemon(cfg, SyntheticDriver({**scene.model_dump(mode="json"), "live": True}))
        thread = threading.Thread(target=daemon.run)
        thread.start()
        try:
            with ViewServer(ZenohConfig(connect=[endpoint]), port=0) as view:
                browser.get(view.url)
                # The moment the ball has crossed about two thirds of its way.
                WebDriverWait(browser, 30).until(
                    lambda b: b.execute_script(
                        "const r = document.querySelector('tr[data-valid=\"true\"]');"
                        "return r !== null && r.dataset.state === 'confirmed';"
                    )
                )
                time.sleep(2.2)
                png = browser.get_screenshot_as_png()
        finally:
            daemon.stop()
            thread.join()
            browser.quit()
    img = Image.open(io.BytesIO(png)).convert("RGB")
    img.quantize(colors=96, method=Image.Quantize.MEDIANCUT).save(out, optimize=True)
    print(f"wrote {out} ({out.stat().st_size // 1024} KB, {img.width}x{img.height} px)")


if __name__ == "__main__":
    main()
