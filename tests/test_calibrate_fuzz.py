"""Fuzzing the image lists of ``stereod calibrate --list``: text lists and OpenCV imagelist
files (XML, YAML). Whatever they hold: a list of pairs of valid names, or one line and a
sysexits code; the list never changes."""

from __future__ import annotations

from hypothesis import example, given
from hypothesis import strategies as st

from stereod.errors import StereodError
from stereod.files.paths import path_problem
from stereod.vision.calibrate import pairs_from_list

from .fuzz import FUZZ, accepted_or_refused, digest

names = st.text(max_size=12) | st.sampled_from(["left01.png", "a b.png", "/abs.png", "../up.png"])


def xml_list(items: list[str]) -> str:
    body = " ".join(f'"{n}"' for n in items)
    return (
        f'<?xml version="1.0"?>\n<opencv_storage>\n<imagelist>\n{body}\n</imagelist>\n'
        "</opencv_storage>\n"
    )


def yaml_list(items: list[str]) -> str:
    body = ", ".join(f'"{n}"' for n in items)
    return f"%YAML:1.0\n---\nimagelist: [ {body} ]\n"


def text_list(items: list[str]) -> str:
    return "\n".join(items) + "\n"


@FUZZ
@given(
    items=st.lists(names, max_size=6),
    form=st.sampled_from([(".xml", xml_list), (".yml", yaml_list), (".txt", text_list)]),
    cut=st.none() | st.integers(0, 200),
)
@example(items=["a", "b"], form=(".xml", xml_list), cut=30)
@example(items=["l.png r.png", "x"], form=(".txt", text_list), cut=None)
def test_image_list(tmp_path_factory, items: list[str], form, cut: int | None) -> None:
    suffix, render = form
    path = tmp_path_factory.mktemp("list") / f"list{suffix}"
    text = render(items)
    path.write_bytes(text.encode()[:cut] if cut is not None else text.encode())
    before = digest(path)
    result = accepted_or_refused(pairs_from_list, path)
    if not isinstance(result, StereodError):
        for left, right in result:
            assert path_problem(str(left)) is None and path_problem(str(right)) is None
    assert digest(path) == before


@FUZZ
@given(data=st.binary(max_size=200), suffix=st.sampled_from([".xml", ".yml", ".txt"]))
def test_image_list_any_bytes(tmp_path_factory, data: bytes, suffix: str) -> None:
    path = tmp_path_factory.mktemp("list") / f"list{suffix}"
    path.write_bytes(data)
    accepted_or_refused(pairs_from_list, path)
