"""``python -m stereod_fakes.world``: the room presets and the transport flags."""

from __future__ import annotations

import pytest

from stereod_fakes.world import main


def test_room_presets_and_transport_flags_are_accepted(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["person_sit_walk", "--stop", "45", "--lit", "--rolling-shutter", "0.02",
                 "--yuyv", "--mjpeg", "75", "--flicker", "0.3"]) == 0  # fmt: skip
    out = capsys.readouterr().out
    assert out.startswith("person_sit_walk: ")
    seconds = float(out.split(": ")[1].split(" s")[0])
    assert seconds > 45.0  # the stop is in the scene
    assert main(["robot_stop_go", "--stop", "2"]) == 0


@pytest.mark.parametrize(
    ("args", "flag"),
    [
        (["person_approach", "--mjpeg", "101"], "--mjpeg"),
        (["person_approach", "--flicker", "1.5"], "--flicker"),
        (["person_approach", "--rolling-shutter", "-0.01"], "--rolling-shutter"),
        (["crossing", "--stop", "3"], "--stop"),
        (["robot_stop_go", "--lit"], "--lit"),
    ],
)
def test_bad_flags_are_one_line_usage_errors(
    args: list[str], flag: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(args) == 64
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f": {flag}: " in err
