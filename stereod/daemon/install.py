"""``stereod install-service``: put the systemd units, the udev rules and a default
configuration in place, and tell udev and systemd when they are running.

With ``prefix`` (for tests and packagers) everything goes under that folder and nothing is
reloaded. A configuration that already exists is never overwritten.
"""

from __future__ import annotations

import importlib.resources
import logging
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from stereod.errors import OutputError, UsageError

log = logging.getLogger(__name__)

UNITS = ("stereod.service", "stereod@.service", "stereod-fuse@.service")
RULES = "60-stereod-minoru.rules"
CONFIG = "stereod.toml"


@dataclass(frozen=True)
class Action:
    """One step: write ``content`` to ``path``, remove ``path``, or run ``command``."""

    kind: str
    path: Path | None = None
    content: str | None = None
    command: tuple[str, ...] = ()

    def describe(self) -> str:
        if self.kind == "write":
            return f"write {self.path}"
        if self.kind == "keep":
            return f"keep {self.path} (exists)"
        if self.kind == "remove":
            return f"remove {self.path}"
        return "run " + " ".join(self.command)


def stereod_executable() -> str:
    """Absolute path of the ``stereod`` command this Python runs."""
    found = shutil.which("stereod")
    if found:
        return str(Path(found).resolve())
    return str(Path(sys.executable).with_name("stereod"))


HIDDEN_FROM_SERVICE = {
    "/home": "ProtectHome=yes",
    "/root": "ProtectHome=yes",
    "/run/user": "ProtectHome=yes",
    "/tmp": "PrivateTmp=yes",
    "/var/tmp": "PrivateTmp=yes",
}
"""Folders the units' sandbox hides from the service, and the setting that hides each."""


def hidden_from_service(executable: str) -> str | None:
    """Why the service could not run ``executable`` (a path the sandbox hides), or None."""
    path = Path(executable)
    for folder, setting in HIDDEN_FROM_SERVICE.items():
        if path.is_relative_to(folder):
            return f"{executable} is under {folder}, which the service cannot see ({setting})"
    return None


def _resource(package: str, name: str) -> str:
    return importlib.resources.files(package).joinpath(name).read_text()


def plan(
    prefix: Path, *, uninstall: bool = False, executable: str | None = None, refuse: bool = True
) -> list[Action]:
    """The steps of an install (or uninstall) under ``prefix`` (``/`` for the real system);
    ``refuse``: a system install of a stereod the service cannot see is a UsageError (off for
    a dry run, which shows the steps all the same)."""
    exe = executable or stereod_executable()
    unit_dir = prefix / "etc/systemd/system"
    rules_dir = prefix / "etc/udev/rules.d"
    config = prefix / "etc/stereod" / CONFIG
    system = prefix == Path("/")
    hidden = hidden_from_service(exe) if system and not uninstall and refuse else None
    if hidden is not None:
        raise UsageError(
            f"install-service: {hidden}: install stereod where a service can run it, e.g. "
            "`sudo python3 -m venv /opt/stereod && sudo /opt/stereod/bin/pip install .`, "
            "then run `sudo /opt/stereod/bin/stereod install-service`"
        )
    actions: list[Action] = []
    if uninstall:
        for path in [*(unit_dir / u for u in UNITS), rules_dir / RULES]:
            if path.exists():
                actions.append(Action("remove", path))
    else:
        for unit in UNITS:
            text = _resource("stereod_systemd", unit).replace("@STEREOD@", exe)
            actions.append(Action("write", unit_dir / unit, text))
        actions.append(Action("write", rules_dir / RULES, _resource("stereod_udev", RULES)))
        if config.exists():
            actions.append(Action("keep", config))
        else:
            actions.append(Action("write", config, _resource("stereod_systemd", CONFIG)))
    if system:
        if Path("/run/udev/control").exists() and shutil.which("udevadm"):
            actions.append(Action("run", command=("udevadm", "control", "--reload")))
            actions.append(
                Action("run", command=("udevadm", "trigger", "--subsystem-match=video4linux"))
            )
        if Path("/run/systemd/system").is_dir() and shutil.which("systemctl"):
            actions.append(Action("run", command=("systemctl", "daemon-reload")))
    return actions


def apply(actions: list[Action]) -> None:
    """Carry the steps out; a step that fails names its path and stops."""
    for a in actions:
        try:
            if a.kind == "write":
                assert a.path is not None and a.content is not None
                a.path.parent.mkdir(parents=True, exist_ok=True)
                a.path.write_text(a.content)
            elif a.kind == "remove":
                assert a.path is not None
                a.path.unlink(missing_ok=True)
            elif a.kind == "run":
                subprocess.run(a.command, check=True, timeout=60)
        except OSError as exc:
            raise OutputError(f"{a.path or a.command[0]}: {exc.strerror or exc}") from exc
        except subprocess.CalledProcessError as exc:
            raise OutputError(
                f"{' '.join(a.command)} failed with exit code {exc.returncode}"
            ) from exc
