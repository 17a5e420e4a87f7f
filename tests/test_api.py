"""The public surface: what ``import stereod`` and ``stereod.client`` export is pinned, the
package is typed, and the documentation's two library examples run."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import stereod
import stereod.client

ROOT = Path(__file__).resolve().parent.parent


def test_top_level_exports_are_pinned() -> None:
    assert sorted(stereod.__all__) == [
        "CalibratedRig",
        "CanonicalRig",
        "Eye",
        "Frame",
        "Geometry",
        "PairResult",
        "Pipeline",
        "PipelineParams",
        "StereoPair",
        "Timings",
        "TrackLifecycle",
        "TrackState",
        "__version__",
    ]
    for name in stereod.__all__:
        assert getattr(stereod, name) is not None


def test_client_exports_are_pinned() -> None:
    assert sorted(stereod.client.__all__) == [
        "DaemonAlive",
        "Event",
        "Image",
        "ImageInfo",
        "ObjectState",
        "ObjectsMessage",
        "QueryError",
        "StatsMessage",
        "StatusMessage",
        "Subscription",
        "TrackEnded",
        "keys",
        "object_events",
        "parse_payload",
        "query_calibration",
        "query_config",
        "query_stats",
        "subscribe_images",
        "subscribe_objects",
        "subscribe_status",
        "wait_alive",
        "zenoh_config",
    ]
    for name in stereod.client.__all__:
        assert hasattr(stereod.client, name), name


def test_package_is_typed() -> None:
    assert (Path(stereod.__file__).parent / "py.typed").is_file()


def readme_examples() -> dict[str, str]:
    """The Python blocks of the README and of the Python API page that start with a
    ``# example: NAME`` line."""
    text = "\n".join((ROOT / name).read_text() for name in ("README.md", "docs/python-api.md"))
    blocks = re.findall(r"```python\n(# example: (\S+)\n.*?)```", text, flags=re.S)
    return {name: code for code, name in blocks}


def test_readme_has_both_library_examples() -> None:
    assert set(readme_examples()) >= {"pipeline", "client"}


def test_readme_pipeline_example_runs(tmp_path: Path) -> None:
    """The notebook example: frames in hand, tracks out, no daemon, no bus."""
    code = readme_examples()["pipeline"]
    res = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=tmp_path
    )
    assert res.returncode == 0, res.stderr
    # The example prints "track <id>: ... heading <deg> deg, <speed> m/s" lines for a ball it
    # renders itself at 90 deg and 0.5 m/s.
    lines = [line for line in res.stdout.splitlines() if line.startswith("track ")]
    assert lines, res.stdout
    heading, speed = (
        float(x) for x in re.findall(r"heading ([\d.]+) deg, ([\d.]+) m/s", lines[-1])[0]
    )
    assert abs(heading - 90.0) < 2.0 and abs(speed - 0.5) < 0.03, lines[-1]
