"""What the daemon's process imports: only what ``stereod run`` needs on every start.

Each module a command needs only sometimes (plotting, MCAP and ROS 2 encoding, browsers for
the viewer's tests, the recorder) stays out of the daemon's memory until it is used. Checked
in a fresh interpreter, which imports the daemon's modules as ``stereod run`` does."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

DAEMON_MODULES = (
    "stereod.cli",
    "stereod.cli.run",
    "stereod.daemon.daemon",
    "stereod.daemon.processing",
)
"""What ``stereod run`` imports before it reads its configuration."""

NOT_IN_THE_DAEMON = (
    "matplotlib",
    "mcap",
    "selenium",
    "scipy",
    "foxglove",
    "websockets",
    "yaml",
    "stereod.ros.export_mcap",
    "stereod.ros.mapping",
    "stereod.ros.mcap_writer",
    "stereod.ros.mcap_run",
    "stereod.sources.recording",
    "stereod.sources.recording_writer",
    "stereod.sources.record",
    "stereod.ros.ros2_live",
    "stereod.view.plot",
    "stereod.view.server",
    "stereod.view.demo",
    "stereod.ros.foxglove",
    "stereod.vision.calibrate",
)
"""Packages and modules only some commands or settings need (``[ros2] enabled`` loads the
ROS 2 encoders when the daemon starts its node)."""


def imported_by(modules: tuple[str, ...], then: str = "") -> set[str]:
    """Every module a fresh interpreter holds after importing ``modules`` and running the
    statement ``then``."""
    code = (
        "import importlib, json, sys\n"
        f"for m in {list(modules)!r}:\n"
        "    importlib.import_module(m)\n"
        f"{then}\n"
        "print(json.dumps(sorted(sys.modules)), file=sys.stderr)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120
    )
    return set(json.loads(out.stderr.strip().splitlines()[-1]))


@pytest.fixture(scope="module")
def daemon_imports() -> set[str]:
    return imported_by(DAEMON_MODULES)


@pytest.mark.parametrize("name", NOT_IN_THE_DAEMON)
def test_the_daemon_does_not_import(name: str, daemon_imports: set[str]) -> None:
    loaded = sorted(m for m in daemon_imports if m == name or m.startswith(name + "."))
    assert not loaded, f"importing the daemon loads {loaded}"


def test_the_check_sees_what_a_module_imports() -> None:
    """The same check finds the ROS 2 encoders where they are imported: it can fail."""
    got = imported_by(("stereod.ros.ros2_live",))
    assert "stereod.ros.mapping" in got and "stereod.ros.ros2_live" in got


NOT_FOR_THE_FLAGS = ("numpy", "cv2", "zenoh", "msgspec", "stereod.pipeline", "stereod.daemon")
"""What ``stereod --help``, a command's ``--help`` and a bad flag never need: every command's
flags are known without the code it runs (most of a second and 50 MB)."""


def test_the_flags_need_none_of_the_pipeline() -> None:
    got = imported_by(("stereod.cli",), "sys.modules['stereod.cli'].build_parser()")
    assert "stereod_fakes.cli" in got and "stereod.cli.fuse" in got  # every command registered
    loaded = sorted(m for m in got for n in NOT_FOR_THE_FLAGS if m == n or m.startswith(n + "."))
    assert not loaded, f"building the command line loads {loaded}"


def test_a_command_loads_what_it_runs() -> None:
    """The same check sees the pipeline once a command runs: it can fail."""
    got = imported_by(
        ("stereod.cli",),
        "sys.modules['stereod.cli'].main(['run', '--check', '--driver', 'synthetic'])",
    )
    assert {"numpy", "cv2", "stereod.daemon.daemon"} <= got


def test_a_client_program_needs_none_of_the_pipeline() -> None:
    """A program that only subscribes (:mod:`stereod.client`) loads no OpenCV and no stage of
    the pipeline: 47 MB and a quarter of a second rather than 68 MB and twice that."""
    got = imported_by(("stereod.client",))
    unwanted = ("cv2", "stereod.pipeline", "stereod.vision.detect", "stereod.daemon.config")
    loaded = sorted(m for m in got for n in unwanted if m == n)
    assert not loaded, f"importing stereod.client loads {loaded}"
