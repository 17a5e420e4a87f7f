"""``stereod devices``: list video capture nodes and find the Minoru's eyes; reset a wedged eye.

A command of this driver package, registered in the ``stereod.commands`` entry-point group.
"""

from __future__ import annotations

import argparse

from stereod.errors import DeviceError, StereodError

from .device import V4L2Device
from .discovery import find_nodes
from .usb import reset


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "devices",
        help="list video capture devices and find the Minoru's eyes",
        description="List capture nodes (sysfs, index 0) with USB ids, port path, bus speed, "
        "formats, frame sizes, frame rates and controls; mark the Minoru eyes (0ac8:3410, "
        "0ac8:3420) and which eye each is by hub port.",
    )
    p.add_argument(
        "--reset",
        choices=["left", "right"],
        metavar="EYE",
        help="USB-reset a wedged eye (left or right)",
    )
    p.add_argument("--brief", action="store_true", help="one line per device, no modes")
    p.set_defaults(func=run)


def run(a: argparse.Namespace) -> int:
    nodes = find_nodes()
    if a.reset:
        eyes = [n for n in nodes if n.eye == a.reset]
        usb = eyes[0].usb if eyes else None
        if usb is None or usb.busnum is None or usb.devnum is None:
            raise DeviceError(
                f"no Minoru {a.reset} eye found to reset: is the camera plugged in? "
                "(see stereod devices)"
            )
        reset(usb.busnum, usb.devnum)
        print(f"reset {a.reset} eye ({eyes[0].device}, USB {usb.port_path})")
        return 0
    if not nodes:
        print("no video capture devices found")
        return 0
    for n in nodes:
        u = n.usb
        where = (
            f"USB {u.vendor}:{u.product} port {u.port_path} {u.speed_mbps:g} Mbit/s"
            if u and u.speed_mbps
            else f"USB {u.vendor}:{u.product} port {u.port_path}"
            if u
            else "not USB"
        )
        mark = f"  Minoru {n.eye} eye" if n.eye else ("  Minoru" if u and u.is_minoru else "")
        print(f"{n.device}: {n.name} ({where}){mark}")
        if a.brief:
            continue
        try:
            with V4L2Device(n.device) as dev:
                for fourcc, desc in dev.formats():
                    print(f"  {fourcc} ({desc})")
                    for w, h in dev.frame_sizes(fourcc):
                        rates = ", ".join(f"{r:g}" for r in dev.frame_rates(fourcc, w, h))
                        print(f"    {w}x{h} at {rates} fps")
                for c in dev.controls():
                    print(f"  control {c.name} [{c.minimum}..{c.maximum}] default {c.default}")
        except StereodError as exc:
            print(f"  cannot query: {exc}")
    return 0
