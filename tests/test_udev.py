"""The udev rules, checked by the real udevadm (design sec. 9): no error line may name them."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

RULES = Path(__file__).resolve().parent.parent / "udev" / "60-stereod-minoru.rules"
RUN_RULES = Path("/run/udev/rules.d")

pytestmark = pytest.mark.skipif(
    shutil.which("udevadm") is None or os.geteuid() != 0,
    reason="needs udevadm (.ci/run installs udev) and root to write /run/udev/rules.d",
)


def udev_complaints(text: str, name: str) -> list[str]:
    """Lines udevadm printed about the rules file ``name``, other than reading it."""
    RUN_RULES.mkdir(parents=True, exist_ok=True)
    target = RUN_RULES / name
    target.write_text(text)
    try:
        out = subprocess.run(
            ["udevadm", "test", "/sys/class/net/lo"], capture_output=True, text=True, timeout=60
        )
    finally:
        target.unlink()
    lines = (out.stdout + out.stderr).splitlines()
    return [line for line in lines if name in line and not line.startswith("Reading rules file")]


def test_rules_parse_without_errors() -> None:
    assert udev_complaints(RULES.read_text(), RULES.name) == []


def test_the_check_catches_a_broken_rule() -> None:
    bad = RULES.read_text().replace('GROUP="video"', 'GROUPX="video"')
    assert any("Invalid key" in line for line in udev_complaints(bad, "61-stereod-broken.rules"))


def test_rules_name_both_eyes_and_tag_for_systemd() -> None:
    text = RULES.read_text()
    assert 'SYMLINK+="minoru/left"' in text and 'SYMLINK+="minoru/right"' in text
    assert 'TAG+="systemd"' in text and 'GROUP="video"' in text and 'ATTR{index}!="0"' in text
