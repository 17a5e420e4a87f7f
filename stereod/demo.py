"""``stereod demo``: the whole system on a scene whose truth is known, in one command.

It renders a ball crossing the default Minoru-like rig (0.060 m, 60 deg, 640x480 at 15 Hz),
replays it through the daemon publishing on a loopback Zenoh endpoint, subscribes to the
``objects`` key from a second session, prints what arrives, and compares the measured heading,
speed and position with the truth.
"""

from __future__ import annotations

import json
import math
import socket
import tempfile
import threading
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from .config import ZenohConfig, load_config
from .daemon import Daemon
from .drivers import load_driver
from .motion import circular_median_deg
from .publish import open_session
from .subscribe import format_object


def free_tcp_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def angle_diff_deg(a: float, b: float) -> float:
    """Smallest signed difference a - b between two headings (deg), in (-180, 180]."""
    d = (a - b + 180.0) % 360.0 - 180.0
    return 180.0 if d == -180.0 else d


def run_demo(
    *,
    rate: float = 1.0,
    keep: Path | None = None,
    heading_deg: float = 60.0,
    speed_mps: float = 0.7,
) -> int:
    """Run the demo; return 0 when heading and speed came out within the paper's own errors."""
    from stereod_fakes.synth import Ball, Scene, write_scene

    scene = Scene(
        balls=[Ball(heading_deg=heading_deg, speed_mps=speed_mps)], drift=0.02, noise_sigma=1.5
    )
    ball = scene.balls[0]
    with tempfile.TemporaryDirectory(prefix="stereod-demo-") as tmp:
        out = keep if keep is not None else Path(tmp) / "scene"
        write_scene(scene, out)
        print(
            f"rendered {scene.n_frames} stereo pairs to {out}: a {ball.radius_m * 100:.0f} cm ball "
            f"at heading {heading_deg:g} deg, {speed_mps:g} m/s, around "
            f"({', '.join(f'{c:g}' for c in ball.centre_m)}) m"
        )
        port = free_tcp_port()
        endpoint = f"tcp/127.0.0.1:{port}"
        cfg = load_config(
            overrides={
                "rig": {"baseline_m": scene.baseline_m, "hfov_deg": scene.hfov_deg},
                "zenoh": {"listen": [endpoint]},
            }
        )
        received: list[dict[str, Any]] = []
        lock = threading.Lock()

        def on_sample(sample: zenoh.Sample) -> None:
            msg = json.loads(sample.payload.to_bytes())
            with lock:
                received.append(msg)
                for o in msg["objects"]:
                    print(f"t {msg['t_ns'] / 1e9:6.3f} s" + format_object(o), flush=True)

        daemon = Daemon(
            cfg, load_driver("replay", {"path": out}), rate=rate, wait_subscriber_s=10.0
        )
        with open_session(ZenohConfig(connect=[endpoint])) as session:
            sub = session.declare_subscriber(
                f"{cfg.zenoh.prefix}/{cfg.rig.name}/objects", on_sample
            )
            summary = daemon.run()
            sub.undeclare()
    if summary.error is not None:
        raise summary.error
    return _report(scene, received)


def _report(scene: Any, received: list[dict[str, Any]]) -> int:
    ball = scene.balls[0]
    states = [(m["t_ns"], o) for m in received for o in m["objects"]]
    valid = [(t, o) for t, o in states if o["velocity_valid"]]
    print()
    if not valid:
        print("no valid velocity was measured: is the ball in view?")
        return 1
    pos_err = []
    bound = []
    for t, o in states:
        truth = ball.position_m((t - scene.t0_ns) / 1e9)
        pos_err.append(float(np.linalg.norm(np.asarray(o["position_m"]) - truth)))
        z = truth[2]
        bound.append(scene.rig.depth_error_one_px_m(z))
    heading = circular_median_deg([o["heading_deg"] for _, o in valid])
    spd = float(np.median([o["speed_mps"] for _, o in valid]))
    raw = [o["raw_velocity_mps"] for _, o in valid if o["raw_velocity_mps"] is not None]
    raw_v = np.median(np.asarray(raw), axis=0)
    raw_heading = math.degrees(math.atan2(raw_v[0], raw_v[2])) % 360.0
    raw_speed = float(np.linalg.norm(raw_v))
    dh = angle_diff_deg(heading, ball.heading_deg)
    ds = spd - ball.speed_mps
    print(
        f"{len(received)} messages, {len(states)} object states, {len(valid)} with valid velocity"
    )
    print(f"{'':24}{'heading (deg)':>14}{'speed (m/s)':>13}")
    print(f"{'true':24}{ball.heading_deg:14.1f}{ball.speed_mps:13.3f}")
    print(f"{'measured (median)':24}{heading:14.1f}{spd:13.3f}")
    print(f"{'paper eq. 21 (median)':24}{raw_heading:14.1f}{raw_speed:13.3f}")
    print(f"{'error':24}{dh:+14.2f}{ds:+13.3f}")
    print(
        f"position error: median {np.median(pos_err) * 100:.1f} cm; eq. 12 one-pixel depth "
        f"error at that range: median {np.median(bound) * 100:.1f} cm"
    )
    ok = abs(dh) <= 5.0 and abs(ds) <= 0.2
    print("within the paper's errors (5 deg, 0.2 m/s)" if ok else "OUTSIDE the paper's errors")
    return 0 if ok else 1
