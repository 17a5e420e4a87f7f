"""Starting ``stereod`` as a separate process, as a user would: one way, for tests and the
benchmarks alike."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent


def stereod_command(*args: str) -> list[str]:
    """The command line of ``stereod ARGS`` with this interpreter (no PATH lookup), through
    the console script's own entry point."""
    return [sys.executable, "-m", "stereod._entry", *args]


def start_stereod(*args: str, env: dict[str, str] | None = None, **popen: Any) -> subprocess.Popen:
    """``stereod ARGS`` in the background, output captured as text unless told otherwise.
    Ctrl-C reaches it as it would from a terminal, even when the tests themselves run as a
    shell's background job (which ignores SIGINT, and a child inherits that)."""
    popen.setdefault("stdout", subprocess.PIPE)
    popen.setdefault("preexec_fn", interruptible)
    popen.setdefault("stderr", subprocess.PIPE)
    popen.setdefault("text", True)
    popen.setdefault("cwd", ROOT)
    return subprocess.Popen(stereod_command(*args), env={**os.environ, **(env or {})}, **popen)


def interruptible() -> None:
    """A ``preexec_fn``: the child takes Ctrl-C's default action (ends), whatever its parent
    ignores."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def run_stereod(
    *args: str,
    timeout: float = 120,
    env: dict[str, str] | None = None,
    cwd: Path = ROOT,
    **kw: Any,
) -> subprocess.CompletedProcess[str]:
    """Run ``stereod ARGS`` to the end (in ``cwd``), capturing text output."""
    return subprocess.run(
        stereod_command(*args),
        capture_output=True,
        text=True,
        timeout=timeout,
        env={**os.environ, **(env or {})},
        cwd=cwd,
        **kw,
    )


def receiver(tmp_path: Path, abstract: bool = False) -> tuple[socket.socket, str]:
    """A datagram socket for sd_notify messages (NOTIFY_SOCKET), at a path or abstract."""
    s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    if abstract:
        name = f"stereod-test-{os.getpid()}-{time.monotonic_ns()}"
        s.bind(b"\0" + name.encode())
        return s, "@" + name
    path = tmp_path / "notify.sock"
    s.bind(str(path))
    return s, str(path)


def collect(sock: socket.socket, until: str, timeout: float) -> list[str]:
    """The sd_notify lines received until one starts with ``until``, or ``timeout`` s pass."""
    got: list[str] = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        sock.settimeout(max(0.01, deadline - time.monotonic()))
        try:
            msg = sock.recv(4096).decode()
        except TimeoutError:
            break
        got += msg.split("\n")
        if any(line.startswith(until) for line in msg.split("\n")):
            break
    return got
