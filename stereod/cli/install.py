"""``stereod install-service``: systemd units, udev rules and a default configuration."""

from __future__ import annotations

import argparse
from pathlib import Path

from stereod.cli.common import path_arg


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "install-service",
        help="install the systemd units, udev rules and a default config",
        description="Write stereod.service, stereod@.service and stereod-fuse@.service (with "
        "this stereod's path), the Minoru udev rules and /etc/stereod/stereod.toml (never "
        "overwritten), then reload udev and systemd when they are running. Then: systemctl "
        "enable --now stereod (a fusion node: stereod-fuse@ROOM, see docs/deployment-room.md).",
    )
    p.add_argument(
        "--prefix",
        type=path_arg,
        default=Path("/"),
        metavar="DIR",
        help="install under DIR instead of / (packaging, tests); nothing is reloaded",
    )
    p.add_argument("--dry-run", action="store_true", help="print the steps, change nothing")
    p.add_argument(
        "--uninstall",
        action="store_true",
        help="remove the units and rules (the configuration stays)",
    )
    p.set_defaults(func=run)


def run(a: argparse.Namespace) -> int:
    from stereod.daemon.install import apply, plan

    actions = plan(a.prefix, uninstall=a.uninstall)
    for action in actions:
        print(("would " if a.dry_run else "") + action.describe())
    if not a.dry_run:
        apply(actions)
    if not actions:
        print("nothing to do")
    return 0
