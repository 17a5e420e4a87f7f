"""Configuration: precedence file < environment < flags, and one-line errors naming the field."""

from __future__ import annotations

from pathlib import Path

import pytest

from stereod.daemon.config import load_config
from stereod.errors import EX_CONFIG, ConfigError, MissingInputError, UsageError
from stereod.tracking.types import TrackerParams


def test_defaults_are_the_minoru() -> None:
    cfg = load_config()
    assert cfg.rig.baseline_m == 0.060 and cfg.rig.name == "minoru"
    assert cfg.zenoh.multicast_scouting is False


def test_precedence(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    f = tmp_path / "c.toml"
    f.write_text('[detector]\nbeta = 0.5\nthreshold = 10\nmin_area_px = 5\n[rig]\nname = "bench"\n')
    monkeypatch.setenv("STEREOD_DETECTOR__THRESHOLD", "30")
    monkeypatch.setenv("STEREOD_DETECTOR__MIN_AREA_PX", "7")
    cfg = load_config(f, {"detector": {"min_area_px": 9, "beta": None}})
    assert (cfg.detector.beta, cfg.detector.threshold, cfg.detector.min_area_px) == (0.5, 30.0, 9)
    assert cfg.rig.name == "bench"


def test_a_flag_naming_another_driver_leaves_the_files_driver_options_out(tmp_path: Path) -> None:
    """``run --config X --driver synthetic`` with X written for replay: replay's ``path`` is
    not the synthetic driver's; the same driver keeps its options."""
    f = tmp_path / "c.toml"
    f.write_text('[driver]\nname = "replay"\n[driver.options]\npath = "/data/run1"\n')
    other = load_config(f, {"driver": {"name": "synthetic"}})
    assert (other.driver.name, other.driver.options) == ("synthetic", {})
    same = load_config(f, {"driver": {"name": "replay"}})
    assert same.driver.options == {"path": "/data/run1"}
    given = load_config(f, {"driver": {"name": "synthetic", "options": {"fps": 15}}})
    assert given.driver.options == {"fps": 15}
    f.write_text('[driver.options]\npath = "/data/run1"\n')  # no name: for whichever runs
    assert load_config(f, {"driver": {"name": "replay"}}).driver.options == {"path": "/data/run1"}


@pytest.mark.parametrize(
    ("toml", "pattern"),
    [
        (
            "[detector]\nbeta = 2.0\n",
            r"c\.toml: invalid config: detector\.beta = 2\.0: Input should be less than 1",
        ),
        ("[detector]\nbta = 0.1\n", r"detector\.bta: unknown field"),
        ("[rig]\nname = 'a b'\n", r"rig\.name = 'a b': use ASCII letters, digits"),
        (
            "[zenoh]\nmode = 'satellite'\n",
            r"zenoh\.mode = 'satellite': Input should be 'peer', 'client' or 'router'",
        ),
        ("[detector\n", r"c\.toml: invalid TOML"),
        (
            "[zenoh]\nmode = 'client'\n",
            r"zenoh: mode = 'client' needs a router to connect to: give zenoh\.connect",
        ),
        (
            "[tracking]\nmax_member_s = -1.0\n",
            r"c\.toml: invalid config: tracking\.max_member_s = -1\.0: must be in 0\.\.600 s",
        ),
        (
            "[tracking]\nmax_member_s = true\n",
            r"tracking\.max_member_s = True: must be a number",
        ),
        (
            "[rig]\ncalibration = ''\n",
            r"rig\.calibration = '': is empty: give a path, or leave the key out",
        ),
        (
            "[matching]\nmin_disparity_px = 10.0\nmax_disparity_px = 5.0\n",
            r"matching\.max_disparity_px = 5\.0: must be larger than min_disparity_px \(10\)",
        ),
        (
            "[tracking]\nfreeze_s = 10\nhold_still_s = 20\n",
            r"c\.toml: tracking\.freeze_s is the older name of tracking\.hold_still_s, which is "
            r"given too: give one of them",
        ),
        (
            "[tracking]\nhold_still_s = 0.5\nstill_after_s = 10\n",
            r"tracking: hold_still_s 0\.5 s is shorter than still_after_s 10 s: .* at least "
            r"still_after_s, or 0 never to hold one",
        ),
        ("[grouping]\nmax_object_size_m = 0\n", r"max_object_size_m = 0: .* greater than or equal"),
        ("[tracking]\nstationary_mps = 1e9\n", r"stationary_mps = 1000000000\.0: .* less than"),
        ("[tracking]\nvalid_speed_sigma_mps = 1e300\n", r"valid_speed_sigma_mps = 1e\+300"),
        ("[detector]\nmax_foreground = 1e-9\n", r"max_foreground = 1e-09: .* greater than"),
    ],
)
def test_bad_values_are_one_line_naming_the_field(tmp_path: Path, toml: str, pattern: str) -> None:
    f = tmp_path / "c.toml"
    f.write_text(toml)
    with pytest.raises(ConfigError, match=pattern) as err:
        load_config(f)
    assert "\n" not in str(err.value)
    assert err.value.exit_code == EX_CONFIG


def test_bad_environment_value(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("STEREOD_RIG__BASELINE_M", "-1")
    with pytest.raises(
        ConfigError, match=r"rig\.baseline_m = '-1': must be in 0\.005\.\.10 m \(UVC camera"
    ):
        load_config()


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(MissingInputError, match="no such config file"):
        load_config(tmp_path / "nope.toml")


def test_environment_reaches_lists_and_driver_options(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("STEREOD_ZENOH__CONNECT", '["tcp/127.0.0.1:7447"]')
    monkeypatch.setenv("STEREOD_DRIVER__OPTIONS__FPS", "30")
    monkeypatch.setenv("STEREOD_DETECTOR__BETA", "0.05")
    cfg = load_config(overrides={"detector": {"beta": 0.07}})
    assert cfg.zenoh.connect == ["tcp/127.0.0.1:7447"]
    assert cfg.driver.options == {"fps": "30"}
    assert cfg.detector.beta == 0.07  # a flag beats the environment
    # A pair is JSON too (it was taken as a string and refused: "a valid tuple").
    monkeypatch.setenv("STEREOD_DETECTOR__SHADOW_RATIO", "[0.3, 0.9]")
    assert load_config().detector.shadow_ratio == (0.3, 0.9)
    # A driver's option written as a JSON list or table is one (the driver knows its types:
    # a scalar stays text for it to read).
    balls = [{"heading_deg": 60, "speed_mps": 0.7}]
    monkeypatch.setenv("STEREOD_DRIVER__OPTIONS__BALLS", ' [{"heading_deg": 60, "speed_mps": 0.7}]')
    monkeypatch.setenv("STEREOD_DRIVER__OPTIONS__CONTROLS", '{"gain": 0}')
    assert load_config().driver.options == {"fps": "30", "balls": balls, "controls": {"gain": 0}}
    # ... and one that does not read as JSON is text (a path may start with "[")
    monkeypatch.setenv("STEREOD_DRIVER__OPTIONS__BALLS", '[{"heading_deg": 60,')
    monkeypatch.setenv("STEREOD_DRIVER__OPTIONS__PATH", "[take 1]/rec")
    options = load_config().driver.options
    assert options["balls"] == '[{"heading_deg": 60,' and options["path"] == "[take 1]/rec"


@pytest.mark.parametrize(
    ("name", "value", "pattern"),
    [
        ("STEREOD_BOGUS__X", "1", "STEREOD_BOGUS__X: names no configuration field"),
        ("STEREOD_DETECTOR", "1", "STEREOD_DETECTOR: names no configuration field"),
        ("STEREOD_DETECTOR__BETA__X", "1", "names no configuration field"),
        ("STEREOD_ZENOH__CONNECT", "foo", "a list or table is written as JSON"),
        ("STEREOD_DETECTOR__BETA", "nan", r"environment STEREOD_DETECTOR__BETA: .*finite"),
    ],
)
def test_bad_environment_is_one_line(
    monkeypatch: pytest.MonkeyPatch, name: str, value: str, pattern: str
) -> None:
    monkeypatch.setenv(name, value)
    with pytest.raises(ConfigError, match=pattern) as err:
        load_config()
    assert "\n" not in str(err.value)


def test_how_long_a_member_is_kept_reaches_the_tracker(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``[tracking] max_member_s`` (the file, then the environment over it) is the tracker's:
    a box a robot pushes for longer than the default 5 s can keep its id."""
    f = tmp_path / "c.toml"
    f.write_text("[tracking]\nmax_member_s = 12.5\n")
    assert load_config(f).tracking.params().max_member_s == 12.5
    monkeypatch.setenv("STEREOD_TRACKING__MAX_MEMBER_S", "30")
    assert load_config(f).tracking.params().max_member_s == 30.0
    assert load_config().tracking.params() == TrackerParams(max_member_s=30.0)


def test_a_config_saved_with_a_byte_order_mark_reads_as_without(tmp_path: Path) -> None:
    """An editor that writes UTF-8 with a BOM (some on Windows do) made the first line an
    'invalid statement' at column 1; the mark is no part of the text."""
    f = tmp_path / "c.toml"
    f.write_bytes("\ufeff[rig]\nbaseline_m = 0.07\n".encode())
    assert load_config(f).rig.baseline_m == 0.07


def test_an_older_name_is_read_from_the_environment_too(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``freeze_s``, ``hold_still_s``'s older name, is read from the environment as from the
    file, and either source's value wins by the sources' order whichever name each gives;
    both names from one source are refused, naming the variables."""
    monkeypatch.setenv("STEREOD_TRACKING__FREEZE_S", "3")
    assert load_config().tracking.hold_still_s == 3.0
    f = tmp_path / "c.toml"
    f.write_text("[tracking]\nhold_still_s = 20\n")
    assert load_config(f).tracking.hold_still_s == 3.0  # the environment over the file
    monkeypatch.delenv("STEREOD_TRACKING__FREEZE_S")
    monkeypatch.setenv("STEREOD_TRACKING__HOLD_STILL_S", "4")
    f.write_text("[tracking]\nfreeze_s = 20\n")
    assert load_config(f).tracking.hold_still_s == 4.0
    monkeypatch.setenv("STEREOD_TRACKING__FREEZE_S", "3")
    with pytest.raises(ConfigError, match=r"STEREOD_TRACKING__HOLD_STILL_S: an older name of it"):
        load_config()


def test_a_sections_own_error_names_where_its_fields_came_from(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An error between a section's fields names the file when one is given, else the
    environment's variables of that section; a field's error, the source of that field
    only (a variable of the same section set for another field is not blamed)."""
    f = tmp_path / "c.toml"
    f.write_text("[tracking]\nstationary_mps = 5\n")
    monkeypatch.setenv("STEREOD_TRACKING__CONFIRM_HITS", "3")
    with pytest.raises(ConfigError, match=r"c\.toml: invalid config: tracking\.stationary"):
        load_config(f)
    monkeypatch.setenv("STEREOD_TRACKING__HOLD_STILL_S", "0.5")
    with pytest.raises(ConfigError, match=r"^environment STEREOD_TRACKING__\*: .* hold_still_s"):
        load_config()
    f.write_text("[detector]\nbeta = 0.05\n")  # a file, with no [tracking]
    with pytest.raises(ConfigError, match=r"^environment STEREOD_TRACKING__\*: .* hold_still_s"):
        load_config(f)
    f.write_text("[tracking]\nstill_after_s = 10\n")
    with pytest.raises(ConfigError, match=r"c\.toml and environment STEREOD_TRACKING__\*: inv"):
        load_config(f)
    monkeypatch.delenv("STEREOD_TRACKING__HOLD_STILL_S")
    monkeypatch.delenv("STEREOD_TRACKING__CONFIRM_HITS")
    with pytest.raises(UsageError, match=r"^command line: invalid config: tracking: hold_still"):
        load_config(None, {"tracking": {"hold_still_s": 0.5, "still_after_s": 10.0}})


def test_holding_a_stopped_object_never_is_allowed(tmp_path: Path) -> None:
    f = tmp_path / "c.toml"
    f.write_text("[tracking]\nhold_still_s = 0\nstill_after_s = 10\n")
    assert load_config(f).tracking.hold_still_s == 0.0


def test_a_stop_longer_than_the_default_hold_lengthens_the_hold(tmp_path: Path) -> None:
    f = tmp_path / "c.toml"
    f.write_text("[tracking]\nstill_after_s = 200\n")
    tracking = load_config(f).tracking
    assert tracking.still_after_s == 200.0 and tracking.hold_still_s == 320.0  # 200 + 120
    assert tracking.params().hold_still_s == 320.0
    assert "hold_still_s" not in tracking.model_fields_set
