"""The processes of a fusion test, set up and torn down in one place: a Zenoh router on
loopback, ``stereod fuse`` connected to it as a client, and rig message generators
(``stereod_fakes.room_messages``, one process per rig, a real Publisher each) or rig daemons.

``with fuse_procs() as run:`` gives the router's endpoint; :meth:`FuseProcs.start_fuse` and
:meth:`FuseProcs.generator` start processes that are all stopped (SIGTERM) at the block's end,
newest first, and the router after them, whatever the test did.
"""

from __future__ import annotations

import contextlib
import json
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tests.processes import start_stereod

from .conftest import ROOT, free_endpoint

ROOM = """\
[room]
name = "lab"
[[room.rigs]]
name = "a"
[[room.rigs]]
name = "b"
translation_m = [4.0, 0.0, 10.0]
rotation_deg = [0.0, 180.0, 0.0]
[[room.rigs]]
name = "c"
translation_m = [4.0, 0.0, 4.0]
rotation_deg = [0.0, -90.0, 0.0]
"""
"""Three rigs: a at the origin, b facing it from 10 m, c at right angles between them."""


def generator(
    room: Path,
    rig: str,
    endpoint: str,
    walkers: str,
    seed: int,
    *extra: str,
    wrap: tuple[str, ...] = (),
) -> subprocess.Popen:
    """A rig message generator for ``rig`` of ``room`` publishing ``walkers`` (JSON) through
    ``endpoint``, once given its t0 (:func:`go`); ``extra``: more of its options; ``wrap``: a
    command it runs under (``("unshare", "-rn")``: its own network namespace)."""
    return subprocess.Popen(
        [*wrap, sys.executable, "-m", "stereod_fakes.room_messages", str(room), rig,
         "--connect", endpoint, "--walkers", walkers, "--seed", str(seed), "--t0-from-stdin",
         *extra],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        cwd=ROOT,
    )  # fmt: skip


def wait_up(proc: subprocess.Popen) -> None:
    """Wait for the generator's ``up`` (its session is open)."""
    assert proc.stdout is not None and proc.stdout.readline().strip() == "up", proc.stderr


def go(proc: subprocess.Popen, t0: int) -> None:
    """Give the generator the walkers' t0 (UTC ns): it publishes from now on."""
    assert proc.stdin is not None
    proc.stdin.write(f"{t0}\n")
    proc.stdin.flush()


def stop(proc: subprocess.Popen) -> None:
    """SIGTERM and wait for the process."""
    proc.send_signal(signal.SIGTERM)
    proc.communicate(timeout=30)


@dataclass
class FuseProcs:
    """The processes of one fusion test around one router at :attr:`endpoint`."""

    endpoint: str
    procs: list[subprocess.Popen] = field(default_factory=list)
    fuse: subprocess.Popen | None = None

    def add(self, proc: subprocess.Popen) -> subprocess.Popen:
        """Stop ``proc`` with the others at the end."""
        self.procs.append(proc)
        return proc

    def start_fuse(self, room: Path, *args: str, **popen: Any) -> subprocess.Popen:
        """``stereod fuse --room ROOM`` as a client of the router, with ``args`` (``popen``:
        for ``subprocess.Popen``, e.g. where its output goes)."""
        fuse = start_stereod(
            "fuse",
            "--room",
            str(room),
            "--connect",
            self.endpoint,
            "--mode",
            "client",
            *args,
            **popen,
        )
        self.fuse = self.add(fuse)
        return fuse

    def generator(
        self,
        room: Path,
        rig: str,
        walkers: str,
        seed: int,
        *extra: str,
        endpoint: str | None = None,
        wrap: tuple[str, ...] = (),
    ) -> subprocess.Popen:
        """A rig message generator through the router (:func:`generator`; at ``endpoint``
        if given, else :attr:`endpoint`), up."""
        at = self.endpoint if endpoint is None else endpoint
        proc = self.add(generator(room, rig, at, walkers, seed, *extra, wrap=wrap))
        wait_up(proc)
        return proc

    def go(self, gens: list[subprocess.Popen], t0: int | None = None) -> int:
        """Start the generators on one t0 (UTC ns; now if not given), which is returned."""
        t0 = time.time_ns() if t0 is None else t0
        for g in gens:
            go(g, t0)
        return t0


ROUTER = """
import json, signal, sys, threading, zenoh
cfg = zenoh.Config()
cfg.insert_json5("mode", '"router"')
cfg.insert_json5("scouting", '{"delay": 0, "multicast": {"enabled": false}}')
cfg.insert_json5("listen/endpoints", sys.argv[1])
done = threading.Event()
signal.signal(signal.SIGTERM, lambda *_: done.set())
with zenoh.open(cfg):
    print("up", flush=True)
    done.wait()
"""
"""A Zenoh router listening on every endpoint of its JSON argument."""


def start_router(endpoints: list[str]) -> subprocess.Popen[str]:
    """A router process listening on ``endpoints``, up."""
    proc = subprocess.Popen(
        [sys.executable, "-c", ROUTER, json.dumps(endpoints)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert proc.stdout is not None and proc.stdout.readline().strip() == "up", proc.stderr
    return proc


@contextlib.contextmanager
def fuse_procs(*listen: str) -> Iterator[FuseProcs]:
    """A router on a free loopback port (and on ``listen``'s endpoints too) and, at the end,
    every process started through the returned :class:`FuseProcs` stopped (newest first),
    then the router."""
    endpoint = free_endpoint()
    router = start_router([endpoint, *listen])
    run = FuseProcs(endpoint)
    try:
        yield run
    finally:
        for p in reversed(run.procs):
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
            with contextlib.suppress(subprocess.TimeoutExpired):
                p.communicate(timeout=30)
        router.terminate()
        router.communicate(timeout=30)
