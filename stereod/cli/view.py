"""``stereod view``: a local web page showing one rig live (images, room map, plots, status)."""

from __future__ import annotations

import argparse
import contextlib
import re
import signal
import threading

from stereod.bus.keys import DEFAULT_RIG, RIG_PATTERN
from stereod.cli.common import DEFAULT_CONNECT, add_zenoh, consumer_zenoh, number, setup_logging
from stereod.cli.interrupt import wait_until
from stereod.cli.signals import relayed
from stereod.errors import ConfigError, UsageError, describe_validation_error


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "view",
        help="a live web page of one rig: images, room map, speed and heading, status",
        description="Subscribes to one rig over Zenoh and serves a web page (no internet "
        "needed) that shows the annotated overlay image, a top view of the room with each "
        "track's trail and velocity, speed and heading of the selected track, and the "
        "daemon's health. The daemon encodes images only while a view (or any subscriber) "
        f"listens. Without --connect, --listen or --zenoh-config it connects to {DEFAULT_CONNECT}.",
    )
    p.add_argument("--rig", default=DEFAULT_RIG, help=f"rig name (default: {DEFAULT_RIG})")
    p.add_argument(
        "--port",
        type=number(0, 65535, integer=True),
        default=8765,
        metavar="N",
        help="TCP port of the page (default 8765; 0: any free port)",
    )
    p.add_argument(
        "--host",
        default="127.0.0.1",
        metavar="ADDR",
        help="address to serve on (default 127.0.0.1: this machine only)",
    )
    g = p.add_argument_group("Foxglove (the same topics and ROS 2 types as `stereod export`)")
    g.add_argument(
        "--foxglove",
        action="store_true",
        help="also serve the rig to the Foxglove app over its WebSocket protocol",
    )
    g.add_argument(
        "--foxglove-port",
        type=number(0, 65535, integer=True),
        default=8766,
        metavar="N",
        help="TCP port of the Foxglove WebSocket (default 8766; 0: any free port)",
    )
    g.add_argument(
        "--foxglove-host",
        default="127.0.0.1",
        metavar="ADDR",
        help="address of the Foxglove WebSocket (default 127.0.0.1: this machine only)",
    )
    add_zenoh(p, listens=False)
    p.set_defaults(func=run)


def run(a: argparse.Namespace) -> int:
    from pydantic import ValidationError

    from stereod.daemon.config_zenoh import ZenohConfig

    setup_logging("WARNING")
    ov = consumer_zenoh(a)
    try:
        zcfg = ZenohConfig(**ov)
    except ValidationError as exc:
        raise ConfigError(f"zenoh flags: {describe_validation_error(exc)}") from exc
    if not re.match(RIG_PATTERN, a.rig):
        raise UsageError(f"--rig {a.rig!r}: use letters, digits, '_' and '-' only")
    from stereod.bus.publish import session_summary
    from stereod.view.server import ViewServer

    done = threading.Event()

    def on_signal(_signum: int) -> None:
        done.set()

    with contextlib.ExitStack() as stack:
        stack.enter_context(relayed(dict.fromkeys((signal.SIGINT, signal.SIGTERM), on_signal)))
        server = stack.enter_context(ViewServer(zcfg, rig=a.rig, host=a.host, port=a.port))
        where = session_summary(zcfg, consumer=True)  # a Zenoh file's mode and endpoints too
        also = ""
        if a.foxglove:
            from stereod.ros.foxglove import FoxgloveBridge

            assert server.session is not None
            bridge = FoxgloveBridge(
                server.session,
                rig=a.rig,
                prefix=zcfg.prefix,
                host=a.foxglove_host,
                port=a.foxglove_port,
            )
            stack.enter_context(bridge)
            also = f", Foxglove at {bridge.url}"
        print(
            f"stereod view: open {server.url}{also} (rig {a.rig}, Zenoh {where}); Ctrl-C to stop",
            flush=True,
        )
        wait_until(done)
    return 0
