"""The note that another daemon publishes this rig's keys: said while the other's statuses
come (or its token was found at open), taken off the status once they stop."""

from __future__ import annotations

import time

import pytest

from stereod.daemon.shared_rig import RIG_SHARED, SharedRig
from stereod.daemon.status import Health
from stereod.sources.pairing import Pairer


def _on_status(h: Health) -> list[str]:
    return [p for p in h.status().problems if p.startswith(RIG_SHARED)]


def test_another_daemon_s_status_is_said_while_it_comes_and_taken_off_after() -> None:
    h = Health("bench", "test", Pairer(), on_change=lambda: None)
    shared = SharedRig(h, "bench")
    shared.check(None, "stereod/bench", 1.0)  # nobody else: nothing said
    assert _on_status(h) == []
    now = time.monotonic()
    shared.check(now - 0.5, "stereod/bench", 1.0)
    shared.check(now - 0.2, "stereod/bench", 1.0)  # said once, not at every tick
    (said,) = _on_status(h)
    assert said.startswith("another stereod publishes rig 'bench' under stereod/bench/ too")
    shared.check(now - 2.9, "stereod/bench", 1.0)  # within 3 s: still there
    assert len(_on_status(h)) == 1
    shared.check(now - 3.5, "stereod/bench", 1.0)  # none for 3 periods (3 s at least): gone
    assert _on_status(h) == []
    assert sum(p.startswith(RIG_SHARED) for p in h.problems()) == 1  # the summary keeps it
    shared.check(now - 0.1, "stereod/bench", 2.0)  # it came back: said again
    shared.check(now - 5.0, "stereod/bench", 2.0)  # 2 s periods: kept for 6 s
    assert len(_on_status(h)) == 1


def test_a_token_found_at_open_is_said_at_once_and_kept_while_no_status_of_the_other_came() -> None:
    """The token found at open is said at once; with no status from the other yet (its lease
    may still be held), the check keeps it."""
    h = Health("bench", "test", Pairer(), on_change=lambda: None)
    shared = SharedRig(h, "bench")
    shared.taken_at_open("stereod/bench")
    shared.check(None, "stereod/bench", 1.0)
    (said,) = _on_status(h)
    assert said.startswith("another stereod already publishes rig 'bench'")


def test_the_note_pushed_off_the_status_by_other_problems_is_said_again(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """The status key shows the last 20 problems: while the other daemon lasts, a note that
    a flapping eye's problems pushed off comes back at the next tick, and is logged as one
    problem (at 1, 10, 100 times), not at each."""
    h = Health("bench", "test", Pairer(), on_change=lambda: None)
    shared = SharedRig(h, "bench")
    shared.check(time.monotonic(), "stereod/bench", 1.0)
    for k in range(20):
        h.problem(f"left eye down ({k})", "eye down")
    assert _on_status(h) == []
    shared.check(time.monotonic(), "stereod/bench", 1.0)
    (said,) = _on_status(h)
    assert "publishes rig 'bench' under stereod/bench/ too" in said
    shared.check(time.monotonic(), "stereod/bench", 1.0)  # there: not said again
    assert sum(p.startswith(RIG_SHARED) for p in h.problems()) == 2
    assert sum(r.getMessage().startswith(RIG_SHARED) for r in caplog.records) == 1


def test_a_token_found_at_open_is_said_again_too_and_goes_when_the_other_s_status_stops() -> None:
    h = Health("bench", "test", Pairer(), on_change=lambda: None)
    shared = SharedRig(h, "bench")
    shared.taken_at_open("stereod/bench")
    for k in range(20):
        h.problem(f"right eye down ({k})", "eye down")
    shared.check(None, "stereod/bench", 1.0)
    (said,) = _on_status(h)
    assert said.startswith("another stereod already publishes rig 'bench'")
    shared.check(time.monotonic() - 0.5, "stereod/bench", 1.0)  # the other's status came
    assert len(_on_status(h)) == 1
    shared.check(time.monotonic() - 3.5, "stereod/bench", 1.0)  # and stopped: gone
    assert _on_status(h) == []
