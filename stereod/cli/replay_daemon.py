"""The daemons a replay runs: one that a signal interrupts (its outputs left as they were),
and one that loops until a signal ends it normally."""

from __future__ import annotations

import logging
import signal

from stereod.bus.messages import DaemonState
from stereod.bus.publish import Publisher
from stereod.cli.common import stdout_gone
from stereod.cli.signals import relayed
from stereod.daemon.daemon import Daemon, RunSummary
from stereod.errors import ConfigError, ReaderGone
from stereod.files.output_file import Interrupted, signal_name

log = logging.getLogger("stereod.cli.replay")


class InterruptibleReplay(Daemon):
    """A replay that a signal (Ctrl-C, SIGTERM) stops before the end of its input: the run
    fails with :class:`Interrupted`, so the daemon discards its JSONL as after any failure,
    instead of committing what played as if it were the whole input. A JSONL written into a
    pipe whose reader closed it ends it too (``--jsonl /dev/stdout | head``)."""

    def _jsonl_reader_gone(self, exc: ReaderGone) -> None:
        self.fail(exc)

    def _rig_taken(self, pub: Publisher) -> None:
        """A replay would mix its messages into a running rig's: refused before it plays."""
        self.fail(
            ConfigError(
                f"another stereod already publishes rig {self.cfg.rig.name!r} under "
                f"{pub.base}/ on this bus; give the replay its own name with --rig NAME"
            )
        )

    def run(self) -> RunSummary:
        caught: list[int] = []  # touched by the signals thread only

        def interrupted(signum: int) -> None:
            ended = self.health.state in (DaemonState.FINISHED, DaemonState.FAILED)
            if not caught and not ended:  # the first wins
                caught.append(signum)
                self.fail(Interrupted(f"interrupted by {signal_name(signum)}", signum))

        signums = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
        with relayed(dict.fromkeys(signums, interrupted)):
            return super().run()


class LoopReplay(Daemon):
    """A replay that plays its input again and again: a signal is its normal end, and so is
    the reader of its JSONL going away (``--loop --jsonl /dev/stdout | head``)."""

    def _jsonl_reader_gone(self, exc: ReaderGone) -> None:
        log.info("%s: stopping", exc)
        if exc.stdout:
            stdout_gone()
        self.stop()
