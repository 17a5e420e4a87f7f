"""The package's shape: sub-packages by job whose imports point one way, few top-level modules,
short modules, and the entry points users and plug-ins rely on."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest
import tomllib

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "stereod"

FORBIDDEN = {
    "vision": {"daemon", "bus", "ros", "view", "cli", "client", "pipeline", "tracking"},
    "tracking": {"daemon", "bus", "ros", "view", "cli", "client", "pipeline"},
    "sources": {"daemon", "bus", "ros", "view", "cli", "client"},
    "files": {"daemon", "bus", "ros", "view", "cli", "client", "pipeline"},
    "fusion": {"daemon", "view", "cli", "client", "pipeline"},
}
"""Which top-level parts of ``stereod`` a sub-package may not import, directly or inside a
function: the image and tracking code knows nothing of the service, the wire or ROS."""

PIPELINE_MAY_IMPORT = {"errors", "sources", "vision", "tracking"}
"""``pipeline.py`` joins vision and tracking and needs nothing else of the package."""

OVER_600: set[str] = set()
"""Modules longer than 600 lines: none, and none may join."""


def _modules() -> list[Path]:
    return sorted(p for p in PACKAGE.rglob("*.py") if "__pycache__" not in p.parts)


def _part(path: Path) -> str:
    """The top-level part a file belongs to: ``vision`` for vision/detect.py, ``pipeline`` for
    pipeline.py."""
    rel = path.relative_to(PACKAGE)
    return rel.parts[0] if len(rel.parts) > 1 else rel.stem


def _imported_parts(path: Path) -> set[str]:
    """Every top-level part of ``stereod`` the module imports, wherever the import stands."""
    parts: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module]
            if node.module == "stereod":
                names = [f"stereod.{a.name}" for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level:
            pytest.fail(f"{path.relative_to(ROOT)}: relative import; write it absolute")
        for name in names:
            bits = name.split(".")
            if bits[0] == "stereod" and len(bits) > 1:
                parts.add(bits[1])
    return parts


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_imports_point_one_way(package: str) -> None:
    found = {
        f"{p.relative_to(PACKAGE)} imports stereod.{part}"
        for p in _modules()
        if _part(p) == package
        for part in _imported_parts(p) & FORBIDDEN[package]
    }
    assert not found, sorted(found)


def test_pipeline_imports_only_vision_and_tracking() -> None:
    extra = _imported_parts(PACKAGE / "pipeline.py") - PIPELINE_MAY_IMPORT
    assert not extra, sorted(extra)


def test_the_import_check_sees_a_forbidden_import(tmp_path: Path) -> None:
    """The check itself: an import of the daemon inside a function is found."""
    bad = tmp_path / "bad.py"
    bad.write_text("def f():\n    from stereod.daemon.daemon import Daemon\n    return Daemon\n")
    assert _imported_parts(bad) == {"daemon"}


def test_few_modules_at_the_top() -> None:
    top = sorted(p.name for p in PACKAGE.glob("*.py"))
    assert len(top) <= 12, top


def test_modules_over_600_lines_only_shrink() -> None:
    long = {
        str(p.relative_to(PACKAGE)) for p in _modules() if len(p.read_text().splitlines()) > 600
    }
    assert long <= OVER_600, f"new modules over 600 lines: {sorted(long - OVER_600)}"
    assert long == OVER_600, f"now under 600 lines, drop from OVER_600: {sorted(OVER_600 - long)}"


def test_every_package_is_installed() -> None:
    """A sub-package missing from pyproject's list would be left out of a wheel."""
    listed = set(
        tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]
    )
    on_disk = {
        ".".join(p.parent.relative_to(ROOT).parts)
        for p in PACKAGE.rglob("__init__.py")
        if "__pycache__" not in p.parts
    }
    assert on_disk <= listed, sorted(on_disk - listed)


def test_entry_points_are_pinned() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["scripts"] == {"stereod": "stereod._entry:main"}
    groups = project["entry-points"]
    assert set(groups["stereod.drivers"]) == {"replay", "synthetic", "v4l2_minoru"}
    assert set(groups["stereod.commands"]) >= {
        "run",
        "replay",
        "subscribe",
        "demo",
        "calibrate",
        "calibration",
        "record",
        "export",
        "plot",
        "view",
        "schema",
        "install-service",
        "synth",
        "devices",
    }


def test_architecture_names_every_module() -> None:
    """ARCHITECTURE.md's picture of the folders names every module in them."""
    text = (ROOT / "ARCHITECTURE.md").read_text()
    tree = text[text.index("stereod/\n") :]
    missing = [
        str(p.relative_to(PACKAGE))
        for p in _modules()
        if p.stem not in ("__init__", "__main__") and not re.search(rf"\b{p.stem}\b", tree)
    ]
    assert not missing, missing
