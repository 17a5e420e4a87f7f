"""Physical bounds at every entry: flags, the TOML config, ``STEREOD_*`` variables, calibration
files and the chessboard square. A value outside is refused in one line naming the flag, field
or file, the value, the range and why: exit 64 for a flag, 78 for the config and for a
calibration file. The README's table of bounds is the code's."""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path
from typing import Any
from unittest import mock

import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st

from stereod import Pipeline, StereoPair
from stereod.cli import main
from stereod.cli.common import load_checked
from stereod.daemon.config import StereodConfig, load_config
from stereod.daemon.params import pipeline_params
from stereod.errors import CalibrationError, ConfigError, StereodError
from stereod.files import bounds
from stereod.files.bounds import BASELINE_M, BOUNDS, HFOV_DEG, SQUARE_M, STATUS_PERIOD_S
from stereod.vision.calibration import Calibration, canonical
from stereod.vision.calibration import load as load_calibration
from stereod.vision.geometry.rectified import CalibratedRig

from .conftest import shared_data
from .fuzz import FUZZ, accepted_or_refused, toml_document

SYNTHETIC = '[driver]\nname = "synthetic"\n[driver.options]\nwidth_px = 160\nheight_px = 120\n'


def refused(capsys: pytest.CaptureFixture[str], argv: list[str], code: int, *patterns: str) -> str:
    """``stereod ARGV`` run in this process ends with ``code`` and one stderr line holding
    every regex of ``patterns``; that line."""
    try:
        got = main(argv)
    except SystemExit as exc:  # the parser's own errors
        got = exc.code  # type: ignore[assignment]
    err = capsys.readouterr().err
    assert got == code, (got, err)
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("stereod"), err
    for pattern in patterns:
        assert re.search(pattern, lines[0]), (pattern, lines[0])
    return lines[0]


@pytest.fixture
def synthetic(tmp_path: Path) -> Path:
    path = tmp_path / "s.toml"
    path.write_text(SYNTHETIC)
    return path


# -- the cases of the review, one each ---------------------------------------------------------


def test_a_vanishing_baseline_flag_is_refused_as_a_flag(
    capsys: pytest.CaptureFixture[str], synthetic: Path
) -> None:
    """``--baseline 1e-300`` made every pair fail with "Singular matrix" and exit 65."""
    refused(
        capsys,
        ["run", "--check", "--config", str(synthetic), "--baseline", "1e-300"],
        64,
        r"--baseline: 1e-300: must be in 0\.005\.\.10 m \(UVC camera boards",
    )


def test_a_vanishing_field_of_view_flag_is_refused_as_a_flag(
    capsys: pytest.CaptureFixture[str], synthetic: Path
) -> None:
    """``--hfov 1e-300`` silently found no objects."""
    refused(
        capsys,
        ["run", "--check", "--config", str(synthetic), "--hfov", "1e-300"],
        64,
        r"--hfov: 1e-300: must be in 5\.\.170 deg \(UVC webcam lenses",
    )


def test_a_vanishing_square_is_refused_as_a_flag(capsys: pytest.CaptureFixture[str]) -> None:
    """``stereod calibrate --square 1e-300`` failed an OpenCV assertion, exit 70."""
    pairs = shared_data("opencv_stereo")
    argv = ["calibrate", "--pairs", str(pairs), "--board", "9x6", "--square", "1e-300"]
    refused(capsys, argv, 64, r"--square: 1e-300: must be in 0\.0001\.\.1 m \(a webcam cannot see")


def _calibration(tmp_path: Path, edit: Any, name: str = "cal.json") -> Path:
    """A canonical calibration of 160x120 frames with ``edit(dict)`` applied and no id."""
    cal = json.loads(canonical(0.06, 60.0, 160, 120).model_dump_json())
    edit(cal)
    cal["id"] = ""
    path = tmp_path / name
    path.write_text(json.dumps(cal))
    return path


def _set(matrix: str, i: int, j: int, value: float) -> Any:
    def edit(cal: dict) -> None:
        cal[matrix][i][j] = value

    return edit


def test_a_calibration_with_a_vanishing_rectified_baseline_fails_run_check(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """P2[0][3] = -1e-300 passed ``run --check`` (and a reload), then every pair with an
    object failed in the pipeline."""
    cal = _calibration(tmp_path, _set("P2", 0, 3, -1e-300))
    cfg = tmp_path / "c.toml"
    cfg.write_text(f'[rig]\ncalibration = "{cal}"\n' + SYNTHETIC)
    refused(
        capsys,
        ["run", "--check", "--config", str(cfg)],
        78,
        r"cal\.json: P2: rectified baseline -P2\[0\]\[3\]/P2\[0\]\[0\] = [\d.]+e-30\d: "
        r"must be in 0\.005\.\.10 m \(UVC camera",
    )


def test_a_playback_rate_that_stands_still_is_refused_as_a_flag(
    capsys: pytest.CaptureFixture[str], synthetic: Path
) -> None:
    """``replay --rate 1e-300`` overflowed the wait for its second frame: exit 70."""
    refused(
        capsys,
        ["run", "--check", "--config", str(synthetic), "--rate", "1e-300"],
        64,
        r"--rate: 1e-300: must be in 0 or 0\.01\.\.1000 x real time \(0 plays as fast",
    )
    assert main(["run", "--check", "--config", str(synthetic), "--rate", "0"]) == 0


def test_a_status_period_that_floods_the_bus_is_refused(tmp_path: Path) -> None:
    """``status_period_s = 1e-9`` sent 4,400 status messages a second."""
    path = tmp_path / "c.toml"
    path.write_text("[daemon]\nstatus_period_s = 1e-9\n")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert re.fullmatch(
        r".*c\.toml: invalid config: daemon\.status_period_s = 1e-09: must be in 0\.05\.\.60 s "
        r"\(20 status messages a second .*\)",
        str(info.value),
    ), str(info.value)


def test_a_bool_is_not_a_number_in_the_config(tmp_path: Path) -> None:
    """``threshold = true`` was read as a threshold of 1 grey level."""
    path = tmp_path / "c.toml"
    path.write_text("[detector]\nthreshold = true\nmin_area_px = false\n")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    text = str(info.value)
    assert "detector.threshold = True: must be a number, not true" in text, text
    assert "detector.min_area_px = False: must be a number, not false" in text, text
    path.write_text("[tracking]\ngravity_mps2 = [0.0, true, 0.0]\n")
    with pytest.raises(ConfigError, match="gravity_mps2: each component must be a number"):
        load_config(path)


# -- every entry of one bound ------------------------------------------------------------------


def test_the_environment_is_held_to_the_same_bounds(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], synthetic: Path
) -> None:
    monkeypatch.setenv("STEREOD_DAEMON__STATUS_PERIOD_S", "1e-9")
    refused(
        capsys,
        ["run", "--check", "--config", str(synthetic)],
        78,
        r"environment STEREOD_DAEMON__STATUS_PERIOD_S: invalid config: "
        r"daemon\.status_period_s = '1e-9': must be in 0\.05\.\.60 s",
    )


def test_a_flag_that_names_a_config_field_is_held_to_its_bound(
    capsys: pytest.CaptureFixture[str], synthetic: Path
) -> None:
    for flag, bound in (("--baseline", BASELINE_M), ("--hfov", HFOV_DEG)):
        for inside in (bound.lo, bound.hi):
            assert main(["run", "--check", "--config", str(synthetic), flag, repr(inside)]) == 0
        capsys.readouterr()
        for outside in (bound.lo * 0.999, bound.hi * 1.001, math.nan, -0.0):
            argv = ["run", "--check", "--config", str(synthetic), flag, repr(outside)]
            wanted = re.escape(bound.range_text())
            refused(capsys, argv, 64, rf"{flag}: .*must be (a finite number )?in {wanted}")
    argv = ["run", "--check", "--config", str(synthetic), "--time-base", "0.001"]
    refused(capsys, argv, 64, r"--time-base: 0\.001: must be in 0\.01\.\.60 s \(tau of eq\. 21")


CONFIG_FIELDS = [
    (b, w) for b in BOUNDS for w in b.where if re.fullmatch(r"[a-z]+\.[a-z_]+", w) is not None
]
"""Each bound's TOML fields (``section.field``)."""


@pytest.mark.parametrize(("bound", "where"), CONFIG_FIELDS, ids=[w for _, w in CONFIG_FIELDS])
def test_every_bounded_config_field_takes_its_ends_and_refuses_beyond(
    tmp_path: Path, bound: bounds.Bound, where: str
) -> None:
    section, field = where.split(".")
    path = tmp_path / "c.toml"
    for inside in (bound.lo, bound.hi) + ((0.0,) if bound.zero_off else ()):
        path.write_text(f"[{section}]\n{field} = {inside!r}\n")
        cfg = load_config(path)
        assert getattr(getattr(cfg, section), field) == inside
    below = bound.lo * 0.999 if bound.lo > 0 else -1e-9
    for outside in (below, bound.hi * 1.001):
        path.write_text(f"[{section}]\n{field} = {outside!r}\n")
        with pytest.raises(ConfigError) as info:
            load_config(path)
        assert f"{where} = {outside!r}: must be in {bound.range_text()} ({bound.why})" in str(
            info.value
        )
        assert info.value.exit_code == 78


def test_a_smallest_disparity_above_the_default_largest_is_refused(tmp_path: Path) -> None:
    """max_disparity_px's check ran only when it was given: min_disparity_px = 1e308 alone
    was accepted, then every pipeline failed to start."""
    path = tmp_path / "c.toml"
    path.write_text("[matching]\nmin_disparity_px = 1e308\n")
    with pytest.raises(ConfigError, match=r"must be larger than min_disparity_px \(1e\+308\)"):
        load_config(path)


MINORU: list[tuple[str, bounds.Bound]] = [
    ("width", bounds.IMAGE_SIDE_PX),
    ("height", bounds.IMAGE_SIDE_PX),
    ("fps", bounds.CAMERA_FPS),
    ("retry_s", bounds.CAMERA_RETRY_S),
    ("retry_max_s", bounds.CAMERA_RETRY_S),
    ("read_timeout_s", bounds.CAMERA_TIMEOUT_S),
    ("stall_s", bounds.CAMERA_STALL_S),
]


@pytest.mark.parametrize(("option", "bound"), MINORU, ids=[o for o, _ in MINORU])
def test_the_camera_drivers_rates_sizes_and_timeouts_are_bounded(
    tmp_path: Path, option: str, bound: bounds.Bound
) -> None:
    """The v4l2_minoru driver's options, checked by ``run --check`` without opening a camera:
    each end is taken, beyond either is refused naming the option, the range and why, and
    true/false is no number."""
    path = tmp_path / "c.toml"
    head = '[driver]\nname = "v4l2_minoru"\n[driver.options]\n'
    # The other two of width, height and fps as small as they go, so that the bus's bandwidth
    # (checked too, at run --check) never decides an end that the bound allows.
    small = {"width": 16, "height": 16, "fps": 1.0}
    rest = "".join(f"{k} = {v!r}\n" for k, v in small.items() if k != option)
    for inside in (bound.lo, bound.hi):
        value = int(inside) if option in ("width", "height") else inside
        path.write_text(f"{head}{option} = {value!r}\n{rest}")
        load_checked(path, {})
    for outside in (bound.lo * 0.9, bound.hi * 1.1, True):
        value = int(outside) if option in ("width", "height") and outside is not True else outside
        text = "true" if value is True else repr(value)
        path.write_text(f"{head}{option} = {text}\n")
        with pytest.raises(ConfigError) as info:
            load_checked(path, {})
        want = "must be a number" if value is True else f"must be in {bound.range_text()}"
        assert f"driver.options.{option} = " in str(info.value), str(info.value)
        assert want in str(info.value), str(info.value)


def test_every_period_rate_and_duration_in_the_config_is_bounded() -> None:
    """A new ``_s``, ``_ms`` or ``_hz`` field of the config needs its bound and reason."""
    timed = {
        f"{section}.{name}"
        for section, sfield in StereodConfig.model_fields.items()
        for name in getattr(sfield.annotation, "model_fields", {})
        if name.endswith(("_s", "_ms", "_hz"))
    }
    assert timed <= {w for _, w in CONFIG_FIELDS}, timed - {w for _, w in CONFIG_FIELDS}
    assert "daemon.status_period_s" in timed and "daemon.image_rate_hz" in timed


def test_the_configuration_reference_has_the_codes_table() -> None:
    """The configuration reference (generated by ``docs/gen_ref.py`` when the site is built)
    lists exactly the code's bounds, with the code's numbers and reasons, under Bounds."""
    from tests.test_docs import gen_ref

    page = gen_ref().config_page()
    table = bounds.markdown_table().rstrip("\n")
    assert table in page, "the configuration reference's bounds table is not stereod.files.bounds'"
    start = page.index(table)
    assert page.rfind("## Bounds", 0, start) == page.rfind("\n## ", 0, start) + 1
    rows = [line for line in table.splitlines()[2:]]
    assert len(rows) == len(BOUNDS)
    for b, row in zip(BOUNDS, rows, strict=True):
        assert f"| {b.range_text()} |" in row


# -- calibration files -------------------------------------------------------------------------


def _scale_p2_baseline(cal: dict) -> None:
    cal["P2"][0][3] *= 2.0


def _wide_focal(cal: dict) -> None:
    for m in ("K1", "K2"):
        cal[m][0][0] = 1e-3


CALIBRATIONS: list[tuple[str, Any, str]] = [
    ("P2 rectified baseline", _set("P2", 0, 3, -1e-300), r"P2: rectified baseline .* 0\.005"),
    ("P2 against |T|", _scale_p2_baseline, r"P2: rectified baseline .* is not \|T\| = 0\.06"),
    ("|T| tiny", _set("T", 0, 0, -1e-4), r"T: baseline \|T\| = 0\.0001: must be in 0\.005"),
    ("|T| huge", _set("T", 0, 0, -60.0), r"T: baseline \|T\| = 60: must be in 0\.005"),
    ("focal", _wide_focal, r"K1: focal length fx = 0\.001 px is outside 6\.999\.\.1832 px"),
    ("principal point", _set("K2", 1, 2, 500.0), r"K2: principal point cy = 500 px"),
    ("Q", _set("Q", 2, 3, 1.0), r"Q: Q\[2\]\[3\] = f of P1 and P2 is 138\.\d+, the file holds 1"),
    ("rotation", _set("R1", 0, 1, 1e-3), r"R1: not a rotation matrix"),
    ("bool entry", _set("K1", 0, 1, True), r"K1: holds true/false"),
]


@pytest.mark.parametrize(
    ("what", "edit", "pattern"), CALIBRATIONS, ids=[c[0] for c in CALIBRATIONS]
)
def test_a_calibration_outside_a_real_rig_is_refused_naming_the_file_and_matrix(
    tmp_path: Path, what: str, edit: Any, pattern: str
) -> None:
    path = _calibration(tmp_path, edit)
    with pytest.raises(CalibrationError) as info:
        load_calibration(path)
    assert re.search(pattern, str(info.value)), str(info.value)
    assert str(info.value).startswith(f"{path}: "), str(info.value)
    assert info.value.exit_code == 78


def test_a_calibration_image_size_and_board_square_are_bounded(tmp_path: Path) -> None:
    path = _calibration(tmp_path, lambda c: c.update(image_size=[160, 100000]))
    with pytest.raises(CalibrationError, match=r"image_size: 160x100000: each side must be in 16"):
        load_calibration(path)
    board = {"cols": 9, "rows": 6, "square": 1e-300}
    path = _calibration(tmp_path, lambda c: c.update(board=board))
    with pytest.raises(
        CalibrationError, match=r"board\.square = 1e-300: must be in 0\.0001\.\.1 m"
    ):
        load_calibration(path)


def test_an_imported_calibrations_size_is_a_flag(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    argv = ["calibration", "import", str(tmp_path / "i.yml"), "--size", "8x6"]
    refused(capsys, argv, 64, r"--size: 8x6: each side must be in 16\.\.8192 px \(no camera mode")


def test_canonical_rigs_at_the_bounds_are_valid_calibrations() -> None:
    """The ends of the baseline and field of view make calibrations that load and rectify."""
    for b in (BASELINE_M.lo, BASELINE_M.hi):
        for fov in (HFOV_DEG.lo, HFOV_DEG.hi):
            cal = canonical(b, fov, 320, 240)
            rig = CalibratedRig(Calibration.model_validate_json(cal.model_dump_json()))
            assert math.isclose(rig.baseline_m, b, rel_tol=1e-9)


# -- fuzz: extreme numbers anywhere ------------------------------------------------------------

EXTREMES = st.sampled_from(
    [
        *(1e-300, -1e-300, 1e308, -1e308, math.nan, math.inf, -math.inf, -0.0, 0.0, 5e-324),
        *(True, False, 2**63, -(2**63)),
    ]
)
"""The numbers that broke things: subnormal, huge, not finite, signed zero, and bools."""

NUMERIC = sorted(
    f"{section}.{name}"
    for section, sfield in StereodConfig.model_fields.items()
    for name, f in getattr(sfield.annotation, "model_fields", {}).items()
    if f.annotation in (int, float)
)


@FUZZ
@given(
    values=st.dictionaries(st.sampled_from(NUMERIC), EXTREMES | st.floats(), min_size=1, max_size=4)
)
@example(values={"daemon.status_period_s": 1e-9})
@example(values={"detector.threshold": True})
@example(values={"rig.baseline_m": -0.0})
def test_extreme_numbers_in_any_numeric_field_are_refused_cleanly(
    tmp_path_factory: pytest.TempPathFactory, values: dict[str, Any]
) -> None:
    tables: dict[str, dict[str, Any]] = {}
    for where, v in values.items():
        section, name = where.split(".")
        tables.setdefault(section, {})[name] = v
    path = tmp_path_factory.mktemp("toml") / "c.toml"
    path.write_text(toml_document(tables))
    result = accepted_or_refused(load_checked, path, {})
    if isinstance(result, StereodError):
        assert result.exit_code == 78, result
        return
    cfg, _ = result
    for where, v in values.items():
        section, name = where.split(".")
        got = getattr(getattr(cfg, section), name)
        assert not isinstance(v, bool) and math.isfinite(got), (where, v, got)
        for b in BOUNDS:
            if where in b.where:
                assert b.problem(got) is None, (where, got)


@FUZZ
@given(where=st.sampled_from(NUMERIC), value=EXTREMES | st.floats())
@example(where="daemon.status_period_s", value=1e-9)
@example(where="detector.threshold", value=True)
def test_extreme_numbers_in_any_environment_variable_are_refused_cleanly(
    where: str, value: Any
) -> None:
    section, name = where.split(".")
    variable = f"STEREOD_{section.upper()}__{name.upper()}"
    text = str(value).lower() if isinstance(value, bool) else repr(value)
    with mock.patch.dict(os.environ, {variable: text}):
        result = accepted_or_refused(load_checked, None, {})
        if isinstance(result, StereodError):
            assert result.exit_code == 78 and (variable in str(result) or name in str(result))
            return
    got = getattr(getattr(result[0], section), name)
    assert math.isfinite(got) and not isinstance(value, bool), (where, text, got)
    for b in BOUNDS:
        if where in b.where:
            assert b.problem(got) is None, (where, got)


WALL = np.random.default_rng(0).integers(0, 200, (48, 64, 3)).astype(np.uint8)


def _eye(x: int | None, shift_px: int) -> np.ndarray:
    """The wall, with a bright 8 px square at column ``x`` less ``shift_px`` (disparity)."""
    image = WALL.copy()
    if x is not None:
        image[20:28, x - shift_px : x - shift_px + 8] = 250
    return image


@FUZZ
@given(
    values=st.dictionaries(
        st.sampled_from(NUMERIC),
        EXTREMES | st.sampled_from([1e9, 1e-9, 1.0, 1000.0]),
        min_size=1,
        max_size=3,
    )
)
@example(values={"matching.centroid_sigma_px": 1e-300})
@example(values={"tracking.manoeuvre_chi2": 1e-300})
@example(values={"matching.min_disparity_px": 1e308})
def test_a_configuration_that_is_accepted_runs(values: dict[str, Any]) -> None:
    """Whatever extreme numbers the config takes, its pipeline starts and follows a square
    moving across 64x48 frames without an exception and with finite tracks: a number that
    would break it is refused where it enters instead."""
    tables: dict[str, dict[str, Any]] = {}
    for where, v in values.items():
        section, name = where.split(".")
        tables.setdefault(section, {})[name] = v
    try:
        cfg = StereodConfig.model_validate(tables)
    except ValueError:
        return
    with Pipeline(pipeline_params(cfg, 64, 48)) as pipe:
        t = 10**9
        for k in range(30):
            x = None if k < 12 else 5 + 2 * (k - 12)
            t += 33_333_333
            result = pipe.process(StereoPair.of(_eye(x, 0), _eye(x, 3), t, t, seq=k))
            for track in result.tracks:
                assert np.all(np.isfinite(track.position_m)), (values, track)
                assert np.all(np.isfinite(track.velocity_mps)), (values, track)


FLAGS = ["--baseline", "--hfov", "--time-base", "--beta", "--threshold", "--min-area", "--warmup"]
FLAGS += ["--rate"]


@FUZZ
@given(flag=st.sampled_from(FLAGS), value=EXTREMES | st.floats() | st.integers())
@example(flag="--baseline", value=1e-300)
@example(flag="--hfov", value=1e-300)
def test_extreme_numbers_in_any_numeric_flag_are_refused_cleanly(
    tmp_path_factory: pytest.TempPathFactory, flag: str, value: Any
) -> None:
    cfg = tmp_path_factory.mktemp("flags") / "s.toml"
    cfg.write_text(SYNTHETIC)
    text = str(value).lower() if isinstance(value, bool) else repr(value)
    try:
        got = main(["run", "--check", "--config", str(cfg), flag, text])
    except SystemExit as exc:
        got = exc.code  # type: ignore[assignment]
    assert got in (0, 64), (flag, text, got)


@FUZZ
@given(
    matrix=st.sampled_from(["K1", "K2", "T", "R1", "R2", "P1", "P2", "Q"]),
    i=st.integers(0, 3),
    j=st.integers(0, 3),
    value=EXTREMES | st.floats(allow_nan=False, allow_infinity=False),
)
@example(matrix="P2", i=0, j=3, value=-1e-300)
def test_extreme_numbers_in_a_calibration_are_refused_or_make_a_working_rig(
    tmp_path_factory: pytest.TempPathFactory, matrix: str, i: int, j: int, value: Any
) -> None:
    def edit(cal: dict) -> None:
        rows = cal[matrix]
        rows[i % len(rows)][j % len(rows[0])] = value

    path = _calibration(tmp_path_factory.mktemp("cal"), edit)
    result = accepted_or_refused(load_calibration, path)
    if isinstance(result, StereodError):
        assert isinstance(result, CalibrationError) and result.exit_code == 78, result
        return
    rig = CalibratedRig(result)
    assert BASELINE_M.problem(rig.baseline_m) is None
    left = rig.rectify_left(np.array([[80.0, 60.0]]))
    right = rig.rectify_right(np.array([[50.0, 60.0]]))
    xyz, cov = rig.triangulate(left, right)
    assert np.all(np.isfinite(xyz)) and np.all(np.isfinite(cov))


def test_bounds_name_their_entries_and_reasons() -> None:
    for b in BOUNDS:
        assert b.where and b.why and b.lo <= b.hi, b
    assert STATUS_PERIOD_S.problem(1e-9) is not None and SQUARE_M.problem(0.025) is None
