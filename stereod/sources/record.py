"""``stereod record``: write what a source delivers into the recording format (design sec. 6).

A live source is read one thread per eye (a camera cannot wait), a file source in timestamp
order; frames keep their capture times and sequence numbers, and their colour (BGR stays BGR,
grey stays grey), so replaying the recording reproduces them exactly (bit for bit with the
lossless FFV1 codec). A target that is a symbolic link is recorded into where it leads (the
link stays), as every output is (:mod:`stereod.files.output_file`).

Whatever fails in either eye's thread (a read, a frame of another size, a full disk, a
callback) stops the whole recording at once, both eyes, and :func:`record` raises the first
failure. As for a full disk, the frames written before it are kept as a recording of their
own (the manifest counts exactly what was written), the error says so, and nothing reports
success: the command exits with the error's code, and ``--mcap`` is not written.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from pathlib import Path

from stereod.errors import DeviceLost, InternalError, StereodError
from stereod.files.output_file import follow_links
from stereod.sources.frames import (
    RETRY_FIRST_S,
    RETRY_MAX_S,
    Driver,
    EyeSource,
    Frame,
    SourceInfo,
    merged,
)
from stereod.sources.recording import Codec
from stereod.sources.recording_writer import RecordingWriter
from stereod.vision.calibration import load as load_calibration

log = logging.getLogger(__name__)


def record(
    driver: Driver,
    out: Path,
    *,
    seconds: float | None = None,
    codec: str = "ffv1",
    calibration: Path | None = None,
    stop: threading.Event | None = None,
    on_frame: Callable[[Frame], None] | None = None,
    on_start: Callable[[SourceInfo, int | None], None] | None = None,
    problems: list[str] | None = None,
) -> dict[str, int]:
    """Record until ``seconds`` of stream time, the end of input or ``stop``; return the frame
    counts per eye. ``out`` must be new (or empty; through a symbolic link, where it leads);
    it appears only when the recording closes, and not at all when no frame came. Frames are
    stored as the source delivers them, BGR or grey (the first frame decides; the manifest's
    ``color`` says which).
    A failure in either eye of a live source stops both and is raised here: a
    :class:`~stereod.errors.StereodError` as it is, anything else as an
    :class:`~stereod.errors.InternalError` naming the eye (the original as its cause). The
    frames written before a failure are kept in ``out`` (see
    :class:`~stereod.sources.recording_writer.RecordingWriter`).
    ``calibration`` is checked as a run would check it, and stored in the manifest.
    ``on_frame`` sees every frame written (progress), one call at a time; ``on_start`` sees
    the opened source and the recording's UTC offset (ns, wall clock minus the frames' clock)
    before the first frame is written: for a source without a clock of its own, the wall clock
    at its first frame, which the manifest keeps too (so a later export stamps as ``--mcap``).
    ``problems``, where given, gets what a file source said of its input (a truncated or
    damaged video, found as it was read): the recording holds what could be read."""
    stop = stop or threading.Event()
    out = follow_links(out)
    cal = load_calibration(calibration).model_dump(mode="json") if calibration else None
    counts = {"left": 0, "right": 0}
    lock = threading.Lock()
    with driver.open() as source:
        info = source.info
        offset = time.time_ns() - time.monotonic_ns() if info.live else info.utc_offset_ns
        if on_start is not None and offset is not None:
            on_start(info, offset)
        first: list[int] = []
        with RecordingWriter(
            out,
            info.width,
            info.height,
            fps=info.fps,
            codec=Codec(codec),
            color=None,
            settings=info.settings,
            utc_offset_ns=offset,
            calibration=cal,
        ) as writer:

            def keep(frame_t: int) -> bool:
                if not first:
                    first.append(frame_t)
                    if offset is None:  # a source without a clock: the wall clock at its start
                        start = time.time_ns() - frame_t
                        writer.set_utc_offset(start)
                        if on_start is not None:
                            on_start(info, start)
                return seconds is None or frame_t - first[0] < seconds * 1e9

            if info.live:
                errors: list[StereodError] = []

                def eye_loop(eye: EyeSource) -> None:
                    pause = 0.0  # a lost camera: at once, then with a backoff (RETRY_FIRST_S)
                    try:
                        while not stop.is_set():
                            try:
                                frame = eye.read()
                            except DeviceLost as exc:
                                if not pause:
                                    log.warning("%s eye lost: %s; retrying", eye.eye.value, exc)
                                if stop.wait(pause):
                                    return
                                pause = min(max(2 * pause, RETRY_FIRST_S), RETRY_MAX_S)
                                continue
                            pause = 0.0
                            if frame is None:
                                return
                            with lock:
                                if errors or not keep(frame.t_ns):
                                    stop.set()
                                    return
                                writer.write(frame)
                                counts[frame.eye.value] += 1
                                if on_frame is not None:
                                    on_frame(frame)
                    except BaseException as exc:  # anything: it ends the recording, both eyes
                        errors.append(_as_error(eye, exc, writer.frames))
                        stop.set()

                threads = [
                    threading.Thread(target=eye_loop, args=(e,), name=f"record-{e.eye.value}")
                    for e in (source.left, source.right)
                ]
                for t in threads:
                    t.start()
                try:
                    while any(t.is_alive() for t in threads):
                        if stop.wait(0.1):
                            source.left.interrupt()
                            source.right.interrupt()
                            for t in threads:
                                t.join(0.1)
                except BaseException:  # the caller's own interruption: the eyes end first
                    stop.set()
                    source.left.interrupt()
                    source.right.interrupt()
                    raise
                finally:
                    for t in threads:
                        t.join()
                if errors:
                    raise errors[0]
            else:
                for frame in merged(source.left, source.right):
                    if stop.is_set() or not keep(frame.t_ns):
                        break
                    writer.write(frame)
                    counts[frame.eye.value] += 1
                    if on_frame is not None:
                        on_frame(frame)
            for name, text in info.files.items():
                writer.write_text(name, text)
            if not writer.frames:  # no recording: one of no frames replays as nothing
                writer.discard()
        if problems is not None and not info.live:
            problems.extend(source.problems() + source.final_problems())
    return counts


def _as_error(eye: EyeSource, exc: BaseException, written: int) -> StereodError:
    """What an eye's thread failed with, as the error :func:`record` raises: a
    :class:`~stereod.errors.StereodError` as it is; anything else (a driver's bug) as an
    :class:`~stereod.errors.InternalError` that names the eye and what the ``written`` frames
    (both eyes) became, the original as its cause (the command line writes both tracebacks
    to its crash log)."""
    if isinstance(exc, StereodError):
        return exc
    what = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
    kept = "the frames recorded so far were kept" if written else "nothing written"
    err = InternalError(
        f"internal error while recording the {eye.eye.value} eye: {what[:200]}; recording "
        f"stopped, {kept}"
    )
    err.__cause__ = exc
    return err
