"""Progress bars for long work (calibrate, synth, replay --rate 0, record, the benchmarks), on
stderr, drawn by tqdm, and only for a person watching a terminal.

A bar is shown only when stderr is a terminal and the process is not run by systemd (which
sets ``INVOCATION_ID`` or ``JOURNAL_STREAM``), so pipes, CI logs and journals get nothing from
it. Everything else a command prints is unchanged. Use::

    from stereod.cli.progress import Progress

    with Progress("render", total=n_frames, unit="frame") as bar:
        for frame in frames:
            ...
            bar.update(1, found=kept)           # a count, and optional figures after it

    # or let a thread read the counters of work running elsewhere, 4 times a second:
    with Progress("replay", total=None, unit="pair", poll=lambda: (pairs(), {"frames": n()})):
        daemon.run()

A bar that is off costs one attribute check per call.
"""

from __future__ import annotations

import os
import sys
import threading
from collections.abc import Callable, Mapping
from typing import Any, TextIO

Poll = Callable[[], tuple[float, dict[str, Any]]]
"""Returns the work done so far (in the bar's unit) and figures to show after it."""


def enabled(stream: TextIO | None = None, environ: Mapping[str, str] | None = None) -> bool:
    """Whether a bar may be drawn on ``stream`` (stderr by default): it is a terminal, and the
    process is not a systemd service."""
    env = os.environ if environ is None else environ
    if env.get("INVOCATION_ID") or env.get("JOURNAL_STREAM"):
        return False
    s = sys.stderr if stream is None else stream
    try:
        return bool(s.isatty())
    except (AttributeError, ValueError):  # no isatty, or a closed stream
        return False


class Progress:
    """One progress bar, or nothing when :func:`enabled` says no (or ``show`` is False).

    ``total`` (in ``unit``s) gives a percentage and an ETA; None counts up with a rate.
    ``poll`` makes a thread refresh the bar from counters kept elsewhere, every ``period_s``.
    """

    def __init__(
        self,
        desc: str,
        *,
        total: float | None = None,
        unit: str = "it",
        poll: Poll | None = None,
        period_s: float = 0.25,
        show: bool | None = None,
    ) -> None:
        self._bar: Any = None
        self._poll = poll
        self._period_s = period_s
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        if not (enabled() if show is None else show):
            return
        from tqdm import tqdm

        self._bar = tqdm(
            desc=desc,
            total=total,
            unit=unit,
            file=sys.stderr,
            dynamic_ncols=True,
            leave=True,
            mininterval=0.1,
        )
        if poll is not None:
            self._thread = threading.Thread(target=self._run, name="progress", daemon=True)
            self._thread.start()

    @property
    def shown(self) -> bool:
        """Whether a bar is drawn."""
        return self._bar is not None

    def update(self, n: float = 1, **figures: Any) -> None:
        """Add ``n`` units of work done; ``figures`` are shown after the bar (name=value)."""
        if self._bar is None:
            return
        if figures:
            self._bar.set_postfix(figures, refresh=False)
        self._bar.update(n)

    def set(self, done: float, **figures: Any) -> None:
        """Set the work done to ``done`` units (absolute), with figures as in :meth:`update`."""
        if self._bar is None:
            return
        if figures:
            self._bar.set_postfix(figures, refresh=False)
        self._bar.update(done - self._bar.n)

    def _run(self) -> None:
        assert self._poll is not None
        while not self._stop.wait(self._period_s):
            self._refresh()

    def _refresh(self) -> None:
        assert self._poll is not None
        try:
            done, figures = self._poll()
        except Exception as exc:  # a counter that cannot be read only stops the bar
            self._bar.set_postfix_str(f"(progress unavailable: {exc})")
            self._stop.set()
            return
        self.set(done, **figures)

    def close(self) -> None:
        """Draw the last state and end the bar's line (idempotent)."""
        if self._bar is None:
            return
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        if self._poll is not None:
            self._refresh()
        self._bar.close()
        self._bar = None

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
