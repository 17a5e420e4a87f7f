"""The bounds every parser's input passes first (stereod.files.nesting): deep nesting and long
numbers are found by a scan that never recurses, in every syntax stereod reads, and the
real files of each kind pass."""

from __future__ import annotations

from pathlib import Path

import cv2
import pytest

from stereod.errors import ConfigError
from stereod.files.nesting import MAX_DEPTH, check_data_depth, check_depth, depth_problem
from stereod.vision.calibration import canonical

ROOT = Path(__file__).resolve().parent.parent


def brackets(n: int) -> str:
    return "[" * n + "1" + "]" * n


@pytest.mark.parametrize("syntax", ["json", "json5", "toml", "yaml"])
def test_bracket_depth_is_bounded_at_max_depth(syntax: str) -> None:
    assert depth_problem(f"a = {brackets(MAX_DEPTH)}", syntax) is None  # type: ignore[arg-type]
    for n in (MAX_DEPTH + 1, 100_000):
        problem = depth_problem(f"a = {brackets(n)}", syntax)  # type: ignore[arg-type]
        assert problem == f"nested deeper than {MAX_DEPTH} levels"


@pytest.mark.parametrize("syntax", ["json", "json5", "toml", "yaml"])
def test_brackets_in_strings_do_not_count(syntax: str) -> None:
    assert depth_problem('{"a": "' + "[" * 500 + '"}', syntax) is None  # type: ignore[arg-type]


def test_comments_hide_brackets_where_the_syntax_has_comments() -> None:
    assert depth_problem("{a: 1} // " + "[" * 500, "json5") is None
    assert depth_problem("a = 1 # " + "[" * 500, "toml") is None
    assert depth_problem("a: 1 # " + "[" * 500, "yaml") is None
    assert depth_problem('{"a": 1} // ' + "[" * 500, "json") is not None  # JSON has none


def test_xml_element_depth() -> None:
    ok = '<?xml version="1.0"?><s><!-- <a><a> --><M1 type_id="opencv-matrix"/></s>'
    assert depth_problem(ok, "xml") is None
    deep = "<s>" + "<a>" * (MAX_DEPTH + 1) + "</a>" * (MAX_DEPTH + 1) + "</s>"
    assert depth_problem(deep, "xml") == f"nested deeper than {MAX_DEPTH} levels"


def test_yaml_indentation_and_dashes_count() -> None:
    block = "".join(" " * i + f"a{i}:\n" for i in range(MAX_DEPTH + 2))
    assert depth_problem(block, "yaml") == f"nested deeper than {MAX_DEPTH} levels"
    dashes = "m:\n  " + "- " * (MAX_DEPTH + 1) + "1\n"
    assert depth_problem(dashes, "yaml") == f"nested deeper than {MAX_DEPTH} levels"


@pytest.mark.parametrize("syntax", ["json", "json5", "toml", "yaml", "xml"])
def test_numbers_of_thousands_of_digits_are_refused(syntax: str) -> None:
    assert depth_problem("a = " + "9" * 1000, syntax) is None  # type: ignore[arg-type]
    problem = depth_problem("a = " + "9" * 5000, syntax)  # type: ignore[arg-type]
    assert problem == "holds a number of more than 1000 digits"


def test_real_files_pass(tmp_path: Path) -> None:
    """The shipped config, a calibration as stereod writes it, and OpenCV's own YAML, XML
    and JSON of the calibration's matrices."""
    assert depth_problem((ROOT / "systemd" / "stereod.toml").read_text(), "toml") is None
    cal = canonical(0.06, 60.0, 640, 480)
    assert depth_problem(cal.model_dump_json(indent=2), "json") is None
    for suffix, syntax in ((".yml", "yaml"), (".xml", "xml"), (".json", "json")):
        path = tmp_path / f"m{suffix}"
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
        for name in ("K1", "D1", "R", "T"):
            fs.write(name, cal.array(name))
        fs.release()
        assert depth_problem(path.read_text(), syntax) is None, path.read_text()  # type: ignore[arg-type]


def test_the_error_names_where_it_came_from() -> None:
    with pytest.raises(ConfigError, match=r"^STEREOD_X: nested deeper than 64 levels"):
        check_depth(brackets(1000), "json", "STEREOD_X", ConfigError)


def test_parsed_data_depth_without_recursion() -> None:
    data: dict = {}
    node = data
    for _ in range(100_000):  # deeper than Python's recursion limit
        node["a"] = {}
        node = node["a"]
    with pytest.raises(ConfigError, match=r"^c\.toml: nested deeper than 64 levels"):
        check_data_depth(data, "c.toml", ConfigError)
    check_data_depth({"a": [{"b": [1, 2]}]}, "c.toml", ConfigError)
