"""Shared fixtures: paths to ../shared/data, loopback Zenoh endpoints, small rendered scenes."""

from __future__ import annotations

import json
import logging
import socket
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from tests.processes import run_stereod

ROOT = Path(__file__).resolve().parent.parent
SHARED_DATA = ROOT.parent / "shared" / "data"


@pytest.fixture(autouse=True)
def _no_handler_outlives_its_test() -> Iterator[None]:
    """A command run in-process sets up logging on the stderr pytest captured for that test;
    the handler goes with the test, so later tests' log records never reach a closed stream."""
    before = set(logging.root.handlers)
    yield
    for handler in list(logging.root.handlers):
        if handler not in before and type(handler) is logging.StreamHandler:
            logging.root.removeHandler(handler)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The slow tests first (each file's order kept): run in parallel, a long test handed out
    last would leave the other workers idle while it finishes."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


def pytest_runtest_setup(item: pytest.Item) -> None:
    """Under ``--dist loadgroup``, a test marked ``xdist_group`` must carry its group in its
    node id (pytest-xdist's worker writes it there as it collects): where it does not, the
    tests of one group run on several workers, each making what they share (a rendered
    scene, a recording) again, and nothing else would say so."""
    if not item.config.getoption("loadgroup", False):  # (set on a worker under loadgroup)
        return
    groups = sorted({str(m.args[0] if m.args else m.kwargs.get("name", "default"))
                     for m in item.iter_markers("xdist_group")})  # fmt: skip
    if groups and not item.nodeid.endswith("@" + "_".join(groups)):
        pytest.fail(
            "--dist loadgroup ignored this test's xdist_group: this pytest and pytest-xdist "
            "do not group (pytest-xdist#1386); install the versions pyproject.toml asks",
            pytrace=False,
        )


def shared_data(*parts: str) -> Path:
    """A path under ../shared/data; skips the test with the reason when it is absent."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"{path} is absent (the shared data folder is not beside the project)")
    return path


def free_endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def zenoh_config(
    *,
    listen: list[str] | None = None,
    connect: list[str] | None = None,
    mode: str | None = None,
) -> zenoh.Config:
    """A test session's config: loopback endpoints, no multicast scouting."""
    cfg = zenoh.Config()
    if mode:
        cfg.insert_json5("mode", json.dumps(mode))
    cfg.insert_json5("scouting", json.dumps({"delay": 0, "multicast": {"enabled": False}}))
    if listen:
        cfg.insert_json5("listen/endpoints", json.dumps(listen))
    if connect:
        cfg.insert_json5("connect/endpoints", json.dumps(connect))
    return cfg


def stereod(
    *args: str, timeout: float = 120, env: dict[str, str] | None = None, **kw: object
) -> subprocess.CompletedProcess[str]:
    """Run ``stereod ARGS`` as a subprocess, capturing text output."""
    return run_stereod(*args, timeout=timeout, env=env, **kw)


@pytest.fixture
def endpoint() -> str:
    return free_endpoint()


@pytest.fixture
def listener(endpoint: str) -> Iterator[zenoh.Session]:
    """A real Zenoh session listening on a loopback endpoint; the daemon connects to it."""
    with zenoh.open(zenoh_config(listen=[endpoint])) as session:
        yield session
