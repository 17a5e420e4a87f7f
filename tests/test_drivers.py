"""Driver discovery through the stereod.drivers entry-point group."""

from __future__ import annotations

import pytest

from stereod.errors import ConfigError
from stereod.sources.drivers import available, load_driver
from stereod_fakes.replay import ReplayDriver
from stereod_fakes.synth import SyntheticDriver


def test_installed_drivers_are_found_by_entry_point() -> None:
    assert {"replay", "synthetic"} <= set(available())
    assert isinstance(load_driver("synthetic", {"fps": 10}), SyntheticDriver)
    assert isinstance(load_driver("replay", {"path": "x"}), ReplayDriver)


def test_unknown_driver_lists_the_installed_ones() -> None:
    with pytest.raises(
        ConfigError, match=r"driver.name = 'nope': no such driver; installed: .*replay"
    ):
        load_driver("nope", {})


def test_driver_option_errors_name_the_option() -> None:
    with pytest.raises(ConfigError, match=r"driver\.options\.fps"):
        load_driver("synthetic", {"fps": -3})
