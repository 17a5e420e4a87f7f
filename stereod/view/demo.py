"""``stereod demo``: the whole system on a scene whose truth is known, in one command.

It has the ``synthetic`` driver render a ball crossing the default Minoru-like rig (0.060 m,
60 deg, 640x480 at 15 Hz) into a recording, replays that through the daemon publishing on a
loopback Zenoh endpoint, receives the ``objects`` messages with :mod:`stereod.client` in a
second session, prints them, and compares the measured heading, speed and position with the
truth. The truth is the ball's straight line, known in closed form from the demo's own
parameters.

With ``view`` it also serves ``stereod view``'s page, prints its address, and plays the scene
once a page is open; the page stays up after the numbers until Ctrl-C.
"""

from __future__ import annotations

import contextlib
import math
import signal
import socket
import tempfile
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import zenoh

from stereod.bus.publish import close_session, open_session, opened_session
from stereod.bus.subscribe import format_object
from stereod.cli.interrupt import wait_until
from stereod.cli.signals import relayed
from stereod.client import Event, ObjectsMessage, subscribe_objects
from stereod.daemon.config import StereodConfig, ZenohConfig, load_config
from stereod.daemon.daemon import Daemon
from stereod.errors import Interrupted, UnavailableError
from stereod.files.output_file import signal_name
from stereod.sources.drivers import load_driver
from stereod.sources.record import record
from stereod.tracking.motion import angle_diff_deg, circular_median_deg
from stereod.vision.geometry.stereo import CanonicalRig

T0_NS = 1_000_000_000
"""Monotonic time of the scene's first frame (ns)."""
DEMO_PORT = 7447
"""The demo listens on tcp/127.0.0.1 at this port when it is free (where ``stereod view``
looks by default), else on any free port."""


def free_tcp_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago (the kernel's pick)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass(frozen=True)
class DemoBall:
    """The demo's ball: at ``t_mid_s`` (s after the first frame) it is at ``centre_m`` (rig
    frame, m) and it moves at ``speed_mps`` along ``heading_deg`` in the XZ plane."""

    heading_deg: float
    speed_mps: float
    centre_m: tuple[float, float, float] = (0.0, 0.1, 1.8)
    radius_m: float = 0.05
    t_on_s: float = 1.2
    t_off_s: float = 2.8

    @property
    def t_mid_s(self) -> float:
        return 0.5 * (self.t_on_s + self.t_off_s)

    @property
    def velocity_mps(self) -> np.ndarray:
        h = math.radians(self.heading_deg)
        return self.speed_mps * np.array([math.sin(h), 0.0, math.cos(h)])

    def position_m(self, t_ns: int) -> np.ndarray:
        """Where the ball is at capture instant ``t_ns`` (m)."""
        t_s = (t_ns - T0_NS) * 1e-9
        return np.asarray(self.centre_m) + (t_s - self.t_mid_s) * self.velocity_mps

    def scene_options(self) -> dict[str, object]:
        """The ``synthetic`` driver's options that render this ball."""
        return {
            "duration_s": 4.0,
            "fps": 15.0,
            "drift": 0.02,
            "noise_sigma": 1.5,
            "t0_ns": T0_NS,
            "balls": [
                {
                    "centre_m": list(self.centre_m),
                    "heading_deg": self.heading_deg,
                    "speed_mps": self.speed_mps,
                    "radius_m": self.radius_m,
                    "t_on_s": self.t_on_s,
                    "t_off_s": self.t_off_s,
                    "t_mid_s": self.t_mid_s,
                }
            ],
        }


def demo_config(endpoint: str, recording: Path) -> StereodConfig:
    """The demo daemon's configuration: the replay of ``recording``, listening on
    ``endpoint``, the rest as the environment and defaults say (what its ``config``
    queryable reports: the replay, not the camera driver the defaults name)."""
    source = {"name": "replay", "options": {"path": str(recording)}}
    return load_config(overrides={"zenoh": {"listen": [endpoint]}, "driver": source})


def run_demo(
    *,
    rate: float = 1.0,
    keep: Path | None = None,
    heading_deg: float = 60.0,
    speed_mps: float = 0.7,
    view: bool = False,
    view_port: int = 8765,
) -> int:
    """Run the demo; return 0 when heading and speed came out within the paper's own errors.
    ``view`` also serves the view page on ``view_port`` (0: any free port) and plays once a
    page is open."""
    ball = DemoBall(heading_deg, speed_mps)
    with _sigterm_as_interrupt(), tempfile.TemporaryDirectory(prefix="stereod-demo-") as tmp:
        out = keep if keep is not None else Path(tmp) / "scene"
        counts = record(load_driver("synthetic", ball.scene_options()), out)
        print(
            f"rendered {counts['left']} stereo pairs to {out}: a {ball.radius_m * 100:.0f} cm "
            f"ball at heading {heading_deg:g} deg, {speed_mps:g} m/s, around "
            f"({', '.join(f'{c:g}' for c in ball.centre_m)}) m"
        )
        with contextlib.ExitStack() as stack:
            zenoh_cfg = load_config().zenoh  # the STEREOD_ZENOH__* variables hold here too
            listening = stack.enter_context(listening_session(base=zenoh_cfg))
            endpoint = listening.endpoint
            cfg = demo_config(endpoint, out)
            received: list[ObjectsMessage] = []
            lock = threading.Lock()
            closed: list[BrokenPipeError] = []

            def on_event(event: Event) -> None:
                if not isinstance(event, ObjectsMessage):
                    return
                with lock:
                    received.append(event)
                    if closed:
                        return
                    try:
                        for o in event.objects:
                            print(f"t {event.t_ns / 1e9:6.3f} s" + format_object(o), flush=True)
                    except BrokenPipeError as exc:  # `stereod demo | head`: the reader had enough
                        closed.append(exc)
                        daemon.stop()

            daemon = Daemon(
                cfg,
                load_driver(cfg.driver.name, cfg.driver.options),  # as config queries say
                rate=rate,
                wait_subscriber_s=10.0,
                session=listening.session,
            )
            if view:
                from stereod.view.server import ViewServer  # aiohttp only when asked for

                page = stack.enter_context(
                    ViewServer(
                        ZenohConfig(connect=[endpoint]),
                        rig=cfg.rig.name,
                        port=view_port,
                        port_flag="--view-port",
                    )
                )
                print(
                    f"view: open {page.url} in a browser; the scene plays once it is open "
                    "(Ctrl-C to stop)",
                    flush=True,
                )
                while not page.connected.wait(0.5):
                    pass
            session = stack.enter_context(
                opened_session(ZenohConfig(connect=[endpoint]), consumer=True)
            )
            stack.enter_context(
                subscribe_objects(session, on_event, rig=cfg.rig.name, prefix=cfg.zenoh.prefix)
            )
            stopped_by: list[int] = []
            with _stopping_on_signals(daemon, stopped_by):
                summary = daemon.run()
            if stopped_by == [signal.SIGINT]:
                raise KeyboardInterrupt  # Ctrl-C, stopped cleanly; the caller exits 130
            if stopped_by:
                name = signal_name(stopped_by[0])
                raise Interrupted(f"demo interrupted by {name}", stopped_by[0])
            if closed:
                raise closed[0]
            if summary.error is not None:
                raise summary.error
            rig = CanonicalRig(cfg.rig.baseline_m, cfg.rig.hfov_deg, 640, 480)
            code = report(ball, rig, received)
            if view:
                print(f"view: the page stays at {page.url} until Ctrl-C", flush=True)
                with contextlib.suppress(KeyboardInterrupt, Interrupted):  # the normal end
                    wait_until(threading.Event())
    return code


@dataclass(frozen=True)
class Listening:
    """A Zenoh session listening on ``endpoint``."""

    session: zenoh.Session
    endpoint: str


@contextlib.contextmanager
def listening_session(
    port: int = DEMO_PORT, base: ZenohConfig | None = None
) -> Iterator[Listening]:
    """The daemon's session, listening from now on so no other process takes its port while
    the demo waits for a page: on tcp/127.0.0.1 at ``port`` (7447: where ``stereod subscribe``
    and ``view`` look by default) unless another program listens there (a port whose last
    connections are in TIME_WAIT is free for it), else on a free port, said on stdout;
    ``base`` gives its other settings."""
    base = base if base is not None else ZenohConfig()
    endpoint = f"tcp/127.0.0.1:{port}"
    try:
        session = open_session(base.model_copy(update={"listen": [endpoint]}))
    except UnavailableError:  # another program listens there
        endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
        session = open_session(base.model_copy(update={"listen": [endpoint]}))
        print(
            f"zenoh: port {port} is taken, listening on {endpoint} "
            f"(stereod subscribe --connect {endpoint})",
            flush=True,
        )
    try:
        yield Listening(session, endpoint)
    finally:
        close_session(session)


@contextlib.contextmanager
def _handling(
    signals: tuple[signal.Signals, ...], handler: Callable[[int, object], None]
) -> Iterator[None]:
    """``handler`` for ``signals`` inside the block, the previous handlers after it; off the
    main thread (where no handler can be set) nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = {s: signal.signal(s, handler) for s in signals}
    try:
        yield
    finally:
        for s, previous in before.items():
            signal.signal(s, previous)


def _sigterm_as_interrupt() -> contextlib.AbstractContextManager[None]:
    """SIGTERM (``timeout``, ``kill``) and SIGHUP end the demo as interrupted, with their own
    line and exit code (143, 129), so whatever it waits for (a page to open, Ctrl-C at the
    end) the scene's temporary folder is removed."""

    def on_signal(signum: int, _frame: object) -> None:
        raise Interrupted(f"demo interrupted by {signal_name(signum)}", signum)

    return _handling((signal.SIGTERM, signal.SIGHUP), on_signal)


def _stopping_on_signals(
    daemon: Daemon, stopped_by: list[int]
) -> contextlib.AbstractContextManager[None]:
    """While the daemon runs, Ctrl-C, SIGTERM or SIGHUP stops it as ``stereod run`` does (its
    threads drain and end, the scene's folder is removed), the signal kept in
    ``stopped_by``."""

    def on_signal(signum: int) -> None:
        stopped_by.append(signum)
        daemon.stop()

    return relayed(dict.fromkeys((signal.SIGINT, signal.SIGTERM, signal.SIGHUP), on_signal))


def report(ball: DemoBall, rig: CanonicalRig, received: list[ObjectsMessage]) -> int:
    """Print measured against true heading, speed and position; 0 within the paper's errors."""
    states = [(m.t_ns, o) for m in received for o in m.objects]
    valid = [o for _, o in states if o.velocity_valid]
    print()
    if not valid:
        print("no valid velocity was measured: is the ball in view?")
        return 1
    truth = np.array([ball.position_m(t) for t, _ in states])
    pos = np.array([o.position_m for _, o in states])
    pos_err = np.linalg.norm(pos - truth, axis=1)
    bound = rig.depth_error_one_px_m(truth[:, 2])
    headed = [o for o in valid if o.heading_valid]
    heading = circular_median_deg([o.heading_deg for o in headed]) if headed else math.nan
    spd = float(np.median([o.speed_mps for o in valid]))
    raw = [o.raw_velocity_mps for o in valid if o.raw_velocity_mps is not None]
    raw_v = np.median(np.asarray(raw), axis=0) if raw else np.full(3, np.nan)
    raw_heading = math.degrees(math.atan2(raw_v[0], raw_v[2])) % 360.0
    raw_speed = float(np.linalg.norm(raw_v))
    dh = angle_diff_deg(heading, ball.heading_deg)
    ds = spd - ball.speed_mps
    print(
        f"{len(received)} messages, {len(states)} object states, {len(valid)} with valid velocity"
        f" ({len(headed)} with a valid heading)"
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
