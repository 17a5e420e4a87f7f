"""Fuzzing the configuration: TOML files, ``STEREOD_`` environment variables and everything a
run reads from them (driver options, the Zenoh settings, the calibration path), as ``run``,
``run --check`` and a reload all load them. Whatever they hold: accepted, or one line and a
sysexits code; the file never changes."""

from __future__ import annotations

import os
from pathlib import Path
from unittest import mock

from hypothesis import example, given, settings
from hypothesis import strategies as st

from stereod.cli.common import load_checked
from stereod.daemon.config import StereodConfig
from stereod.errors import StereodError
from stereod_fakes.replay import ReplayOptions
from stereod_fakes.synth import Scene, SynthFlags
from stereod_v4l2_minoru.driver import MinoruOptions

from .fuzz import (
    FUZZ,
    SYSEXITS,
    accepted_or_refused,
    deep_json,
    deep_toml,
    digest,
    not_killed,
    toml_document,
    toml_values,
)
from .processes import run_stereod

SECTIONS = {
    name: sorted(field.annotation.model_fields)  # type: ignore[union-attr]
    for name, field in StereodConfig.model_fields.items()
}
DRIVER_OPTIONS = sorted(
    {*ReplayOptions.model_fields, *Scene.model_fields, *SynthFlags.model_fields}
    | {*MinoruOptions.model_fields}
)


def section(name: str) -> st.SearchStrategy[dict]:
    keys = st.sampled_from([*SECTIONS[name], "bogus"])
    if name == "driver":
        return st.fixed_dictionaries(
            {},
            optional={
                "name": st.sampled_from(["replay", "synthetic", "v4l2_minoru", "nope"]),
                "options": st.dictionaries(
                    st.sampled_from(DRIVER_OPTIONS), toml_values, max_size=4
                ),
            },
        )
    return st.dictionaries(keys, toml_values, max_size=4)


documents = st.lists(st.sampled_from(sorted(SECTIONS)), unique=True, max_size=4).flatmap(
    lambda names: st.fixed_dictionaries({n: section(n) for n in names})
)
"""TOML documents made of the config's own tables and fields, holding any values."""


def check_file(path: Path) -> None:
    before = digest(path)
    result = accepted_or_refused(load_checked, path, {})
    if not isinstance(result, StereodError):
        cfg, _driver = result
        assert isinstance(cfg, StereodConfig)
    assert digest(path) == before, "loading the config changed the file"


@FUZZ
@given(tables=documents)
@example(tables={"zenoh": {"connect": "foo"}})
@example(tables={"zenoh": {"listen": ["tcp/nonsense:99999"]}})
@example(tables={"driver": {"name": "v4l2_minoru", "options": {"fps": -15}}})
@example(tables={"driver": {"name": "synthetic", "options": {"width_px": 100000}}})
@example(tables={"driver": {"name": "replay", "options": {"fps": 1e-300, "left_video": "a"}}})
@example(tables={"daemon": {"log_level": "LOUD"}})
@example(tables={"rig": {"calibration": "\x00"}})
def test_structured_toml(tmp_path_factory, tables: dict) -> None:
    path = tmp_path_factory.mktemp("toml") / "c.toml"
    path.write_text(toml_document(tables))
    check_file(path)


@FUZZ
@given(data=st.binary(max_size=300) | st.text(max_size=300).map(str.encode))
@example(data=b'[rig]\nname = "\xff"\n')
@example(data=b"\xff\xfe[x")
@example(data=b"[detector]\nbeta = nan\n")
def test_any_bytes_as_toml(tmp_path_factory, data: bytes) -> None:
    path = tmp_path_factory.mktemp("toml") / "c.toml"
    path.write_bytes(data)
    check_file(path)


names = st.one_of(
    st.sampled_from(sorted(SECTIONS)).flatmap(
        lambda sec: st.sampled_from(SECTIONS[sec]).map(lambda f: f"STEREOD_{sec}__{f}".upper())
    ),
    st.sampled_from(DRIVER_OPTIONS).map(lambda o: f"STEREOD_DRIVER__OPTIONS__{o.upper()}"),
    st.text(
        st.sampled_from("ABCDEFGHIJKLMNOPQRSTUVWXYZabcxyz0123456789_"), min_size=1, max_size=12
    ).map(lambda t: f"STEREOD_{t}"),
)
"""Variable names: a config field's, a driver option's, or anything after the prefix."""
env_values = st.text(
    st.characters(blacklist_characters="\x00", blacklist_categories=["Cs"]), max_size=30
) | st.sampled_from(["nan", "1e400", "-1", "[]", '["tcp/127.0.0.1:1"]', "foo", "LOUD", "r\udcff"])


@FUZZ
@given(env=st.dictionaries(names, env_values, max_size=3))
@example(env={"STEREOD_ZENOH__CONNECT": "foo"})
@example(env={"STEREOD_BOGUS__X": "1"})
@example(env={"STEREOD_RIG__CALIBRATION": "r\udcff"})
def test_environment(env: dict[str, str]) -> None:
    clean = {k: v for k, v in os.environ.items() if not k.upper().startswith("STEREOD_")}
    with mock.patch.dict(os.environ, {**clean, **env}, clear=True):
        result = accepted_or_refused(load_checked, None, {})
    if not isinstance(result, StereodError):
        assert isinstance(result[0], StereodConfig)


@FUZZ
@given(text=deep_toml())
@example(text="a = " + "[" * 520 + "]" * 520 + "\n")
def test_deeply_nested_toml(tmp_path_factory, text: str) -> None:
    """TOML nesting deeper than any config (tomllib's recursion ran out at ~500 levels: an
    internal error, 70), or holding numbers of thousands of digits: accepted or one line."""
    path = tmp_path_factory.mktemp("toml") / "c.toml"
    path.write_text(text)
    check_file(path)


@FUZZ
@given(value=deep_json())
@example(value="[" * 100_000 + "]" * 100_000)
def test_deeply_nested_environment_json(value: str) -> None:
    """A list or table variable given as deeply nested JSON: accepted or one line."""
    clean = {k: v for k, v in os.environ.items() if not k.upper().startswith("STEREOD_")}
    with mock.patch.dict(os.environ, {**clean, "STEREOD_ZENOH__CONNECT": value}, clear=True):
        accepted_or_refused(load_checked, None, {})


@settings(FUZZ, max_examples=6, deadline=None)  # whole processes: each takes about a second
@given(text=deep_json())
@example(text="{mode: " + "[" * 100_000 + "]" * 100_000 + "}")
def test_deeply_nested_zenoh_file_in_a_process(tmp_path_factory, text: str) -> None:
    """A Zenoh config file (JSON5) nesting far deeper than any real one, as ``run --check``
    reads it: Zenoh's parser overflowed its stack on it (SIGSEGV, and a daemon restarted
    into it for ever); now one line and exit 78, or accepted, never a signal."""
    d = tmp_path_factory.mktemp("zenoh")
    (d / "z.json5").write_text(text)
    (d / "c.toml").write_text(f'[zenoh]\nconfig_file = "{d / "z.json5"}"\n')
    res = run_stereod("run", "--check", "--config", str(d / "c.toml"), timeout=120, cwd=d)
    not_killed(res.returncode, res.stderr[-300:])
    assert res.returncode in {0} | (SYSEXITS - {70}), res.stderr
    if res.returncode:
        assert len(res.stderr.splitlines()) == 1, res.stderr
