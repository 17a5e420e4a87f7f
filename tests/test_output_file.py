"""The output rule: where an output path is written, and what is refused before any work."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import pytest

from stereod.errors import OutputError
from stereod.output_file import AtomicOutput, output_target


def test_a_regular_file_is_replaced_by_rename_and_a_link_is_written_through(
    tmp_path: Path,
) -> None:
    real = tmp_path / "real.jsonl"
    real.write_text("old\n")
    link = tmp_path / "link.jsonl"
    link.symlink_to(real.name)
    assert output_target(real) == (real, False)
    assert output_target(link) == (real, False)
    with AtomicOutput(link) as out:
        out.write(b"new\n")
    assert link.is_symlink() and real.read_text() == "new\n"


def test_a_device_is_written_in_place_and_a_folder_is_refused(tmp_path: Path) -> None:
    assert output_target(Path("/dev/null")) == (Path("/dev/null"), True)
    with pytest.raises(OutputError, match="is a directory; give the name of a file in it"):
        output_target(tmp_path)
    with pytest.raises(OutputError, match=r"folder .*nowhere does not exist"):
        output_target(tmp_path / "nowhere" / "x.mcap")


def _refuses(path: Path) -> str | None:
    """The OutputError's text for an output at ``path``, or None if it is accepted."""
    try:
        AtomicOutput(path).discard()
    except OutputError as exc:
        return str(exc)
    return None


def test_a_write_protected_file_is_refused_and_left_as_it_was() -> None:
    """Renaming over a read-only file would succeed (its folder is writable), but a shell's
    ``>`` refuses it, and so does every output here. Root may write any file, so as root the
    check runs in a child process that has become the user nobody."""
    folder = Path(tempfile.mkdtemp(prefix="stereod-ro-", dir="/tmp"))  # nobody can reach it
    try:
        folder.chmod(0o777)
        path = folder / "keep.json"
        path.write_text("precious\n")
        path.chmod(0o444)
        if os.geteuid() != 0:
            message = _refuses(path)
        else:
            read, write = os.pipe()
            pid = os.fork()
            if pid == 0:  # the child: answer through the pipe, then leave at once
                try:
                    os.setuid(65534)
                    os.write(write, (_refuses(path) or "accepted").encode())
                except BaseException as exc:
                    os.write(write, f"the check failed: {exc!r}".encode())
                finally:
                    os._exit(0)
            os.close(write)
            with os.fdopen(read) as answer:
                message = answer.read()
            os.waitpid(pid, 0)
        assert message is not None and "keep.json: this user may not write the file" in message, (
            message
        )
        assert path.read_text() == "precious\n" and sorted(folder.iterdir()) == [path]
    finally:
        shutil.rmtree(folder)
