"""``stereod install-service``: systemd units, udev rules and a default configuration."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from stereod.cli.common import path_arg
from stereod.errors import UsageError
from stereod.files.paths import shown


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
        type=_prefix_arg,
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


def _prefix_arg(text: str) -> Path:
    """An argparse type: a folder to install under; an empty one (which would be the folder
    the command runs in) is refused."""
    if not text.strip():
        raise argparse.ArgumentTypeError("is empty: give a folder, or leave --prefix out for /")
    return path_arg(text)


def run(a: argparse.Namespace) -> int:
    from stereod.daemon.install import apply, hidden_from_service, plan, stereod_executable

    if a.prefix.exists() and not a.prefix.is_dir():
        raise UsageError(
            f"--prefix {shown(a.prefix)}: not a folder; give the folder to install under"
        )
    actions = plan(a.prefix, uninstall=a.uninstall, refuse=not a.dry_run)
    exe = stereod_executable()
    system = a.prefix == Path("/") and not a.dry_run  # (refused by plan)
    hidden = None if a.uninstall or system else hidden_from_service(exe)
    if hidden is not None:  # the system install refuses this; a staged or dry one is said to
        print(
            f"stereod install-service: warning: {hidden}: the units written run it and cannot "
            "start once installed; install stereod where a service can run it (e.g. "
            "/opt/stereod)" + (" (the install itself refuses)" if a.dry_run else ""),
            file=sys.stderr,
            flush=True,
        )
    unsaid: OSError | None = None  # stdout failed: the install goes on, whole
    for action in actions:
        if not a.dry_run:
            apply([action])  # said once done: a step that fails is the last line
        if unsaid is None:
            try:
                print(("would " if a.dry_run else "") + action.describe(), flush=True)
            except OSError as exc:  # a reader gone (`| head`) or a full disk
                unsaid = exc
    if unsaid is not None:
        raise unsaid  # every step done; the command line says what became of stdout
    if not actions:
        print("nothing to do")
    return 0
