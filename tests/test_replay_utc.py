"""``stereod replay --utc-start T``: the first frame's UTC instant, so that several replays of
one scene (one per rig) stamp their messages on one clock."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from stereod.sources.recording import MANIFEST, read_frame_index, read_manifest
from stereod_fakes.synth import Scene, write_scene
from tests.processes import run_stereod

LOOPBACK = ("--listen", "tcp/127.0.0.1:0")


@pytest.fixture(scope="module")
def rec(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_scene(Scene(duration_s=1.0, fps=15), tmp_path_factory.mktemp("utc") / "rec")


def first_frame_ns(rec: Path) -> int:
    man = read_manifest(rec)
    firsts = [int(read_frame_index(rec / e.timestamps)[0][0]) for e in (man.left, man.right)]
    return min(firsts)


@pytest.mark.parametrize(
    ("given", "utc_ns"),
    [
        ("2026-03-01T12:00:00.25Z", 1_772_366_400_250_000_000),
        ("2026-03-01T13:00:00.25+01:00", 1_772_366_400_250_000_000),
        ("1772366400250000000", 1_772_366_400_250_000_000),
    ],
)
def test_utc_start_puts_the_first_frame_at_that_instant(
    rec: Path, tmp_path: Path, given: str, utc_ns: int
) -> None:
    out = tmp_path / "run.jsonl"
    res = run_stereod(
        "replay", str(rec), "--rate", "0", "-q", "--utc-start", given, "--jsonl", str(out),
        *LOOPBACK,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    msgs = [json.loads(line) for line in out.read_text().splitlines()]
    assert msgs and (rec / MANIFEST).exists()
    t0 = first_frame_ns(rec)
    for m in msgs:
        assert m["stamp_utc_ns"] - m["t_ns"] == utc_ns - t0
        for o in m["objects"]:
            assert o["stamp_utc_ns"] == m["stamp_utc_ns"]


@pytest.mark.parametrize("bad", ["2026-03-01T12:00:00", "yesterday", "2026-13-01T00:00:00Z"])
def test_a_bad_utc_start_is_one_line_and_exit_64(rec: Path, bad: str) -> None:
    res = run_stereod("replay", str(rec), "--rate", "0", "--utc-start", bad, *LOOPBACK)
    assert res.returncode == 64
    assert res.stderr.count("\n") == 1 and "--utc-start" in res.stderr
    assert "unrecognized" not in res.stderr  # refused for its value, naming what to give


@pytest.mark.parametrize("late", [str(2**63 - 1), "2100-01-01T00:00:00.000000001Z"])
def test_a_utc_start_past_2100_is_refused(rec: Path, late: str) -> None:
    """The first frame's instant may not be one whose stream time could pass 64 bits (at
    2^63 - 1 the stamps did, and a fusion node fed them died): 1970..2100, leaving 16 years
    of stream within the 2116 every reader takes; one line, exit 64."""
    res = run_stereod("replay", str(rec), "--rate", "0", "--utc-start", late, *LOOPBACK)
    assert res.returncode == 64, res.stderr
    assert res.stderr.count("\n") == 1 and "--utc-start" in res.stderr
    assert "outside 1970..2100" in res.stderr, res.stderr


def test_a_utc_start_after_2038_is_refused_with_mcap(rec: Path, tmp_path: Path) -> None:
    """A ROS 2 stamp holds seconds in 32 bits: with ``--mcap`` a start after 2038-01-19 is
    refused before anything runs, naming the flag (it failed at the first message, exit 65);
    without ``--mcap`` it plays."""
    later = "2100-01-01T00:00:00Z"
    res = run_stereod(
        "replay", str(rec), "--rate", "0", "--utc-start", later, "--mcap", str(tmp_path / "r.mcap"),
        *LOOPBACK,
    )  # fmt: skip
    assert res.returncode == 64, res.stderr
    assert res.stderr.startswith("stereod: --utc-start 4102444800000000000 ns: after 2038-01-19")
    assert not (tmp_path / "r.mcap").exists()
    res = run_stereod("replay", str(rec), "--rate", "0", "-q", "--utc-start", later, *LOOPBACK)
    assert res.returncode == 0, res.stderr
