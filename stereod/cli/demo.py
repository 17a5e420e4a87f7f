"""``stereod demo``: render a scene, replay it, watch it arrive over Zenoh, compare."""

from __future__ import annotations

import argparse

from stereod.cli.common import add_rate, number, path_arg, setup_logging


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "demo",
        help="render a scene, replay it, watch it arrive over Zenoh, compare with the truth",
        description="Renders a ball crossing the default rig's view at a known heading and "
        "speed, replays it through the daemon in real time, prints positions and velocities as "
        "they arrive over Zenoh, and ends with measured against true heading and speed.",
    )
    add_rate(p, "playback speed (0: as fast as possible)")
    p.add_argument("--keep", type=path_arg, metavar="DIR", help="keep the rendered recording here")
    p.add_argument(
        "--heading",
        type=number(-360.0, 720.0, unit="deg"),
        default=60.0,
        help="true heading, deg (60)",
    )
    p.add_argument(
        "--speed", type=number(0.05, 3.0, unit="m/s"), default=0.7, help="true speed, m/s (0.7)"
    )
    p.add_argument(
        "--view",
        action="store_true",
        help="also serve the live page of `stereod view`, print its address, and play once "
        "it is open in a browser",
    )
    p.add_argument(
        "--view-port",
        type=number(0, 65535, integer=True),
        default=8765,
        metavar="N",
        help="TCP port of the page on 127.0.0.1 (default 8765; 0: any free port)",
    )
    p.set_defaults(func=run)


def run(a: argparse.Namespace) -> int:
    from stereod.view.demo import run_demo

    setup_logging("WARNING")
    return run_demo(
        rate=a.rate,
        keep=a.keep,
        heading_deg=a.heading % 360.0,
        speed_mps=a.speed,
        view=a.view,
        view_port=a.view_port,
    )
