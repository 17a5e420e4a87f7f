"""The output rule: where an output path is written, and what is refused before any work."""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
import threading
import time
from pathlib import Path

import pytest

from stereod.errors import OutputError, ReaderGone, UsageError
from stereod.files.output_file import AtomicOutput, check_outputs, give_up_writing, output_target


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


def test_a_pipe_whose_reader_stops_reading_is_given_up_once_asked() -> None:
    """A write into a full pipe waits for its reader, but once :func:`give_up_writing` is
    called the wait is bounded, and the reader counts as gone instead of holding the writer
    (and whoever waits for it) for good."""
    read_fd, write_fd = os.pipe()
    try:
        out = AtomicOutput(Path(f"/proc/self/fd/{write_fd}"))
        failure: list[BaseException] = []
        written = threading.Event()

        def writer() -> None:
            try:
                for _ in range(64):  # 4 MB: far more than a pipe holds
                    out.write(b"x" * 65536)
                written.set()
            except BaseException as exc:
                failure.append(exc)

        t = threading.Thread(target=writer)
        t.start()
        assert os.read(read_fd, 65536)  # the reader reads a little, then stops
        t.join(1.0)
        assert t.is_alive() and not written.is_set()  # held by the reader, as it should be
        give_up_writing(0.3)
        t.join(5.0)
        assert not t.is_alive()
        assert len(failure) == 1 and isinstance(failure[0], ReaderGone), failure
        assert "its reader stopped reading" in str(failure[0])
        out.discard()
    finally:
        os.close(read_fd)
        with contextlib.suppress(OSError):
            os.close(write_fd)


def test_a_stall_limit_gives_up_a_reader_that_stops_reading_and_keeps_one_that_reads() -> None:
    """:meth:`AtomicOutput.limit_stall`: a write that waits longer than the limit for the
    pipe's reader fails as the reader gone, naming the limit; a slow reader that takes data
    within it is written to the end."""
    read_fd, write_fd = os.pipe()
    try:
        out = AtomicOutput(Path(f"/proc/self/fd/{write_fd}"))
        out.limit_stall(0.3)
        with pytest.raises(ReaderGone, match=r"its reader took nothing for 0\.3 s"):
            for _ in range(64):  # 4 MB: far more than a pipe holds, and nobody reads
                out.write(b"x" * 65536)
                out.flush()
        out.discard()
    finally:
        os.close(read_fd)
        with contextlib.suppress(OSError):
            os.close(write_fd)
    read_fd, write_fd = os.pipe()
    got = bytearray()

    def slow() -> None:
        while chunk := os.read(read_fd, 65536):
            got.extend(chunk)
            time.sleep(0.05)

    reader = threading.Thread(target=slow)
    reader.start()
    try:
        with AtomicOutput(Path(f"/proc/self/fd/{write_fd}")) as out:
            out.limit_stall(0.3)
            for k in range(40):
                out.write(bytes([k]) * 65536)
    finally:
        os.close(write_fd)
        reader.join(10)
        os.close(read_fd)
    assert bytes(got) == b"".join(bytes([k]) * 65536 for k in range(40))


def test_a_reader_that_reads_gets_everything() -> None:
    read_fd, write_fd = os.pipe()
    got = bytearray()
    reader = threading.Thread(target=lambda: _drain(read_fd, got))
    reader.start()
    try:
        with AtomicOutput(Path(f"/proc/self/fd/{write_fd}")) as out:
            for k in range(200):
                out.write(bytes([k]) * 10000)
    finally:
        os.close(write_fd)
        reader.join(10)
        os.close(read_fd)
    assert bytes(got) == b"".join(bytes([k]) * 10000 for k in range(200))


def _drain(fd: int, into: bytearray) -> None:
    while chunk := os.read(fd, 65536):
        into.extend(chunk)


def test_an_output_that_is_an_input_is_refused_through_links(tmp_path: Path) -> None:
    """The one output rule against inputs: the same path, a symbolic link to an input (also
    one that is not there yet: realpath), a hard link (st_dev/st_ino), a file inside an input
    folder; one line naming the flag and the input, exit 64, nothing written."""
    rec = tmp_path / "rec"
    rec.mkdir()
    (rec / "left.mkv").write_bytes(b"video")
    cfg = tmp_path / "c.toml"
    cfg.write_text("")
    os.link(cfg, tmp_path / "hard.mcap")
    (tmp_path / "soft.mcap").symlink_to(rec / "left.mkv")
    (tmp_path / "dangling.mcap").symlink_to(tmp_path / "later.csv")
    cases = [
        (tmp_path / "hard.mcap", cfg),
        (tmp_path / "soft.mcap", rec / "left.mkv"),
        (rec / "left.mkv", rec / "left.mkv"),
        (tmp_path / "dangling.mcap", tmp_path / "later.csv"),
    ]
    for out, found in cases:
        with pytest.raises(UsageError) as exc:
            check_outputs({"--mcap": out}, [cfg, None, rec, tmp_path / "later.csv"])
        assert exc.value.exit_code == 64
        assert str(exc.value).startswith(f"--mcap {out}: that is an input of this run ({found})")
    check_outputs({"--mcap": tmp_path / "new.mcap", "--jsonl": None}, [cfg, rec])
    assert (rec / "left.mkv").read_bytes() == b"video" and cfg.read_text() == ""


def test_two_outputs_that_are_one_file_are_refused(tmp_path: Path) -> None:
    (tmp_path / "a.jsonl").symlink_to(tmp_path / "b.mcap")
    with pytest.raises(UsageError, match=r"^--jsonl .*a\.jsonl and --mcap .*b\.mcap are the same"):
        check_outputs({"--jsonl": tmp_path / "a.jsonl", "--mcap": tmp_path / "b.mcap"}, [])
