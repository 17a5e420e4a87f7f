"""Service files: install under a prefix, and the real systemd tooling's verdict on the units."""

from __future__ import annotations

import ipaddress
import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from stereod.daemon.install import UNITS, hidden_from_service, plan
from stereod.errors import EX_CONFIG, EX_DATAERR, EX_NOINPUT, UsageError

from .conftest import stereod
from .processes import stereod_command

SYSTEMD_ANALYZE = shutil.which("systemd-analyze")
needs_systemd = pytest.mark.skipif(
    SYSTEMD_ANALYZE is None, reason="systemd-analyze is not installed (.ci/run installs it)"
)


STAGED_WARNING = "stereod install-service: warning:"
"""How the line begins that a staged install of a stereod the service cannot see adds (this
checkout's, when it is under /tmp or /home)."""


def installed(tmp_path: Path) -> Path:
    res = stereod("install-service", "--prefix", str(tmp_path))
    assert res.returncode == 0, res.stderr
    return tmp_path / "etc/systemd/system"


def test_install_dry_run_and_uninstall(tmp_path: Path) -> None:
    dry = stereod("install-service", "--prefix", str(tmp_path), "--dry-run")
    assert dry.returncode == 0 and "would write" in dry.stdout
    assert not (tmp_path / "etc").exists()
    units = installed(tmp_path)
    text = (units / "stereod.service").read_text()
    exe = re.search(r"^ExecStart=(\S+) run", text, re.M)
    assert exe and Path(exe.group(1)).is_absolute() and "@STEREOD@" not in text
    assert (tmp_path / "etc/udev/rules.d/60-stereod-minoru.rules").is_file()
    cfg = tmp_path / "etc/stereod/stereod.toml"
    cfg.write_text("# mine\n")
    again = stereod("install-service", "--prefix", str(tmp_path))
    assert "keep" in again.stdout and cfg.read_text() == "# mine\n"
    gone = stereod("install-service", "--prefix", str(tmp_path), "--uninstall")
    assert gone.returncode == 0
    assert not (units / "stereod.service").exists() and cfg.exists()


def test_a_prefix_that_is_no_folder_or_empty_is_refused_and_only_what_was_done_is_said(
    tmp_path: Path,
) -> None:
    """A file as --prefix said five writes, then failed on the first (exit 73); an empty one
    installed into ./etc. Both are one line and 64 now, nothing written; a step that fails
    under a prefix is the last line, after the steps done before it."""
    afile = tmp_path / "afile"
    afile.write_text("")
    for prefix, why in ((str(afile), "not a folder"), ("", "is empty")):
        res = stereod("install-service", "--prefix", prefix, cwd=tmp_path)
        assert res.returncode == 64 and res.stdout == "", res
        assert len(res.stderr.splitlines()) == 1 and why in res.stderr, res.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]
    blocked = tmp_path / "p"
    (blocked / "etc/udev").mkdir(parents=True)
    (blocked / "etc/udev/rules.d").write_text("a file where a folder goes")
    res = stereod("install-service", "--prefix", str(blocked))
    assert res.returncode == 73, res.stderr
    said = res.stdout.splitlines()
    assert len(said) == len(UNITS) and all(line.startswith("write ") for line in said), said
    assert "rules.d" in res.stderr and not any("rules" in line for line in said)


def test_default_config_is_valid_and_listens_on_loopback_only(tmp_path: Path) -> None:
    installed(tmp_path)
    res = stereod("run", "--config", str(tmp_path / "etc/stereod/stereod.toml"), "--check")
    assert res.returncode == 0, res.stderr
    zenoh = json.loads(res.stdout)["zenoh"]
    assert zenoh["listen"] and zenoh["connect"] == [] and not zenoh["multicast_scouting"]
    for endpoint in zenoh["listen"]:
        host = endpoint.split("/", 1)[1].rsplit(":", 1)[0].strip("[]")
        assert ipaddress.ip_address(host).is_loopback, f"{endpoint} is reachable from the LAN"


@pytest.mark.parametrize(
    ("executable", "setting"),
    [("/home/ann/stereod/.venv/bin/stereod", "ProtectHome"), ("/tmp/x/bin/stereod", "PrivateTmp")],
)
def test_a_system_install_refuses_a_stereod_the_service_cannot_see(
    executable: str, setting: str
) -> None:
    """The units hide /home, /root and /tmp from the service: a unit that runs a stereod from
    there could never start, so the install says so and where to put stereod instead."""
    with pytest.raises(UsageError, match=f"{re.escape(executable)} is under .*{setting}.*/opt"):
        plan(Path("/"), executable=executable)
    assert plan(Path("/"), executable=executable, uninstall=True) is not None  # may remove
    assert hidden_from_service("/opt/stereod/bin/stereod") is None
    assert hidden_from_service("/usr/local/bin/stereod") is None


@pytest.mark.parametrize(
    "executable, warned",
    [("/tmp/x/bin/stereod", True), ("/home/ann/.venv/bin/stereod", True),
     ("/opt/stereod/bin/stereod", False)],
)  # fmt: skip
def test_a_staged_install_of_a_stereod_the_service_cannot_see_is_warned_of(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    executable: str,
    warned: bool,
) -> None:
    """Under --prefix (a package staged, a test) the install goes on, but units that run a
    stereod under /tmp or /home could never start once installed: one warning line says so
    (it wrote them in silence)."""
    import stereod.daemon.install as install
    from stereod.cli import main

    monkeypatch.setattr(install, "stereod_executable", lambda: executable)
    assert main(["install-service", "--prefix", str(tmp_path)]) == 0
    unit = (tmp_path / "etc/systemd/system/stereod.service").read_text()
    assert f"ExecStart={executable} run" in unit
    err = capsys.readouterr().err
    if warned:
        assert err.count("\n") == 1 and err.startswith(STAGED_WARNING)
        assert f"warning: {executable} is under" in err and "cannot start" in err
    else:
        assert err == ""


def test_a_dry_run_of_a_system_install_the_service_cannot_see_shows_its_steps(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """A dry run changes nothing, so it shows the steps of a system install (it refused, and
    showed none, for a stereod under /tmp), with the one warning that the install refuses."""
    import stereod.daemon.install as install
    from stereod.cli import main

    monkeypatch.setattr(install, "stereod_executable", lambda: "/tmp/x/bin/stereod")
    assert main(["install-service", "--dry-run"]) == 0
    out, err = capsys.readouterr()
    assert "would write /etc/systemd/system/stereod.service" in out
    assert err.count("\n") == 1 and "(the install itself refuses)" in err
    assert main(["install-service"]) == 64  # (refused before any step)
    assert "is under /tmp" in capsys.readouterr().err


@pytest.mark.parametrize("unit", ["stereod.service", "stereod@.service", "stereod-fuse@.service"])
def test_the_service_does_not_restart_into_a_bad_or_missing_configuration(
    tmp_path: Path, unit: str
) -> None:
    """A configuration that is invalid (78) or missing (66), or a file driver's input that
    ended bad (65), stays so on a restart: systemd must not loop on it every two seconds."""
    text = (installed(tmp_path) / unit).read_text()
    m = re.search(r"^RestartPreventExitStatus=(.+)$", text, re.M)
    assert m, text
    assert {str(EX_CONFIG), str(EX_NOINPUT), str(EX_DATAERR)} <= set(m.group(1).split())


def test_no_reload_under_a_prefix(tmp_path: Path) -> None:
    assert all(a.kind != "run" for a in plan(tmp_path))


@needs_systemd
@pytest.mark.parametrize("unit", ["stereod.service", "stereod@.service", "stereod-fuse@.service"])
def test_units_verify_clean_and_score_at_most_2(tmp_path: Path, unit: str) -> None:
    units = installed(tmp_path)
    target = units / unit
    name = unit.replace("@.", "@bench.") if "@" in unit else unit
    if name != unit:
        shutil.copy(target, units / name)
        target = units / name
    verify = subprocess.run(
        [SYSTEMD_ANALYZE, "verify", str(target)],
        capture_output=True,
        text=True,
        cwd=units,
        timeout=60,
    )
    # systemd 252 exits 0 even with warnings: any output is a failure.
    assert verify.stdout + verify.stderr == "", verify.stdout + verify.stderr
    sec = subprocess.run(
        [SYSTEMD_ANALYZE, "security", "--offline=true", str(target)],
        capture_output=True,
        text=True,
        cwd=units,
        timeout=60,
    )
    m = re.search(r"Overall exposure level for \S+: ([0-9.]+)", sec.stdout)
    assert m, sec.stdout + sec.stderr
    assert float(m.group(1)) <= 2.0, sec.stdout


def test_the_help_names_every_unit_it_writes(tmp_path: Path) -> None:
    """``install-service --help`` lists the units the command writes, all of them."""
    written = sorted(p.name for p in installed(tmp_path).glob("*.service"))
    assert written == sorted(UNITS)
    text = " ".join(stereod("install-service", "--help").stdout.split())
    assert all(unit in text for unit in UNITS), text


def test_stdout_that_fails_leaves_no_install_half_done(tmp_path: Path) -> None:
    """``> /dev/full`` stopped the install after its first file (exit 70), ``| head -1`` after
    its second: every step is done first now, then the line about stdout (exit 74), or
    nothing for a reader that went away (exit 0)."""
    whole = tmp_path / "whole"
    assert stereod("install-service", "--prefix", str(whole)).returncode == 0
    files = sorted(p.relative_to(whole) for p in whole.rglob("*") if p.is_file())
    assert len(files) >= 5
    full = tmp_path / "full"
    with open("/dev/full", "w") as out:
        res = subprocess.run(
            stereod_command("install-service", "--prefix", str(full)),
            stdout=out, stderr=subprocess.PIPE, text=True, timeout=60,
        )  # fmt: skip
    assert res.returncode == 74, res.stderr
    assert sorted(p.relative_to(full) for p in full.rglob("*") if p.is_file()) == files
    head = tmp_path / "head"
    cmd = " ".join(stereod_command("install-service", "--prefix", str(head))) + " | head -1"
    piped = subprocess.run(["bash", "-o", "pipefail", "-c", cmd], capture_output=True, text=True)
    said = [line for line in piped.stderr.splitlines() if not line.startswith(STAGED_WARNING)]
    assert piped.returncode == 0 and said == [], piped.stderr  # a clone under /tmp is warned of
    assert sorted(p.relative_to(head) for p in head.rglob("*") if p.is_file()) == files
