"""The room file: its model, its validation and the rig-to-room rotation convention."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from stereod.errors import EX_CONFIG, EX_NOINPUT, ConfigError, MissingInputError
from stereod.fusion.room import load_room, rotation_matrix

ROOM = """\
[room]
name = "lab"
[[room.rigs]]
name = "a"
translation_m = [0.0, 0.0, 0.0]
rotation_deg = [0.0, 0.0, 0.0]
[[room.rigs]]
name = "b"
translation_m = [4.0, 0.0, 4.0]
rotation_deg = [0.0, -90.0, 0.0]
"""


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "room.toml"
    path.write_text(text)
    return path


def closed_form_zyx(rx: float, ry: float, rz: float) -> np.ndarray:
    """The Z-Y-X (yaw, pitch, roll) rotation written out element by element."""
    cx, sx = math.cos(math.radians(rx)), math.sin(math.radians(rx))
    cy, sy = math.cos(math.radians(ry)), math.sin(math.radians(ry))
    cz, sz = math.cos(math.radians(rz)), math.sin(math.radians(rz))
    return np.array(
        [
            [cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx],
            [sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx],
            [-sy, cy * sx, cy * cx],
        ]
    )


@pytest.mark.parametrize("angles", [(10.0, -25.0, 40.0), (-170.0, 80.0, 5.0), (0.0, 0.0, 0.0)])
def test_rotation_is_the_closed_form_z_y_x_rotation(angles: tuple[float, float, float]) -> None:
    r = rotation_matrix(*angles)
    np.testing.assert_allclose(r, closed_form_zyx(*angles), atol=1e-12)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)


def test_rotation_turns_the_rig_axes_as_documented() -> None:
    """A rig turned +90 deg about Y looks along the room's +X; +90 about Z puts its right
    (X) on the room's +Y (down); +90 about X puts its forward (Z) on the room's -Y (up)."""
    np.testing.assert_allclose(rotation_matrix(0, 90, 0) @ [0, 0, 1], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(rotation_matrix(0, 0, 90) @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(rotation_matrix(90, 0, 0) @ [0, 0, 1], [0, -1, 0], atol=1e-12)
    # Intrinsic order: first about Z (right -> room +Y), then about the new Y (the room's
    # -X), which turns the rig's right from the room's +Y to its -Z.
    np.testing.assert_allclose(rotation_matrix(0, 90, 90) @ [1, 0, 0], [0, 0, -1], atol=1e-12)


def test_room_file_loads_and_maps_rig_points_into_the_room(tmp_path: Path) -> None:
    room = load_room(write(tmp_path, ROOM))
    assert room.name == "lab" and [r.name for r in room.rigs] == ["a", "b"]
    b = room.rig("b")
    assert b is not None
    # Rig b stands at (4, 0, 4) looking along the room's -X: 2 m in front of it is (2, 0, 4).
    p = b.rotation() @ np.array([0.0, 0.0, 2.0]) + b.translation()
    np.testing.assert_allclose(p, [2.0, 0.0, 4.0], atol=1e-12)


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        (('name = "b"', 'name = "a"'), "rig 'a' is listed twice"),
        (("[4.0, 0.0, 4.0]", "[4.0, nan, 4.0]"), r"room\.rigs\.1\.translation_m\.1"),
        (("[4.0, 0.0, 4.0]", "[4.0, 0.0, 4000.0]"), r"translation_m: must be in -1000\.\.1000 m"),
        (("[0.0, -90.0, 0.0]", "[0.0, true, 0.0]"), "rotation_deg.*not true/false"),
        (("[4.0, 0.0, 4.0]", '["4", "0", "4"]'), r"translation_m: needs three .*not quoted"),
        (("[0.0, -90.0, 0.0]", "[0.0, -90.0, inf]"), r"rotation_deg\.2"),
        (("[0.0, -90.0, 0.0]", "[0.0, 400.0]"), r"rotation_deg: needs three numbers .*not 2"),
        (("[4.0, 0.0, 4.0]", "[4.0, 0.0, 4.0, 1.0]"), r"translation_m: needs three .*not 4"),
        (
            ('name = "lab"', 'name = "lab/x"'),
            r"room\.name = 'lab/x': use ASCII letters, digits, '_' and '-' only",
        ),
        (
            ("rotation_deg = [0.0, -90", "rotatoin_deg = [0.0, -90"),
            r"rotatoin_deg: unknown field \(did you mean rotation_deg\?\)",
        ),
    ],
)
def test_a_bad_room_file_is_one_line_naming_the_field(
    tmp_path: Path, change: tuple[str, str], expected: str
) -> None:
    path = write(tmp_path, ROOM.replace(*change))
    with pytest.raises(ConfigError, match=expected) as info:
        load_room(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)
    assert info.value.exit_code == EX_CONFIG


def test_a_room_file_nested_too_deep_or_missing_is_refused(tmp_path: Path) -> None:
    deep = ROOM + "x = " + "[" * 200 + "]" * 200 + "\n"
    with pytest.raises(ConfigError, match="nested deeper than"):
        load_room(write(tmp_path, deep))
    dotted = "[room]\n" + "a." * 100 + "b = 1\n"
    with pytest.raises(ConfigError, match="nested deeper than"):
        load_room(write(tmp_path, dotted))
    with pytest.raises(MissingInputError, match="no such room file") as info:
        load_room(tmp_path / "absent.toml")
    assert info.value.exit_code == EX_NOINPUT


def test_a_room_file_saved_with_a_byte_order_mark_reads_as_without(tmp_path: Path) -> None:
    f = tmp_path / "room.toml"
    f.write_bytes(("\ufeff" + ROOM).encode())
    room = load_room(f)
    assert room.name == "lab" and [r.name for r in room.rigs] == ["a", "b"]


def test_a_room_with_no_rig_says_so_in_words(tmp_path: Path) -> None:
    """Not pydantic's "List should have at least 1 item after validation, not 0"."""
    path = write(tmp_path, '[room]\nname = "lab"\nrigs = []\n')
    with pytest.raises(ConfigError, match=r"room\.rigs: needs at least 1 item$"):
        load_room(path)


def test_every_name_pattern_of_the_files_is_said_in_words() -> None:
    """A name that breaks a pattern is told what the pattern allows, not the regular
    expression: each pattern the configuration and room files use has its words."""
    from stereod.bus import keys
    from stereod.daemon.config import Ros2Config
    from stereod.errors import _PATTERNS

    namespace = Ros2Config.model_fields["namespace"].metadata[0].pattern
    assert {keys.RIG_PATTERN, keys.PREFIX_PATTERN, namespace} <= set(_PATTERNS)
