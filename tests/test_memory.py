"""The allocator setting that gives freed background-sized buffers back to the system and
keeps frame-sized ones in the heap."""

from __future__ import annotations

import os
import platform
import subprocess
import sys
from pathlib import Path

import pytest

from stereod.daemon.memory import MIN_MMAP_THRESHOLD, separate_large_buffers

W, H = 640, 480

CHILD = """
import re, sys
import numpy as np
from stereod.daemon.memory import separate_large_buffers
def rss_kb():
    return int(re.search(r"VmRSS:\\s+(\\d+)", open("/proc/self/status").read()).group(1))
if sys.argv[1] == "set":
    assert separate_large_buffers({w}, {h}) is not None
kept = []
for size in ({w} * {h} * 4, {w} * {h} * 3):  # a grey float32 background, then a BGR frame
    before = rss_kb()
    for _ in range(2):  # glibc's own way: the first free raises its thresholds
        block = np.ones(size, np.uint8)
        del block
    kept.append(rss_kb() - before)
print(*kept)
"""


def kept_kb(mode: str) -> tuple[int, int]:
    """RSS (kB) a fresh process keeps after allocating and freeing, twice, a block the size
    of a grey float32 background, and then one the size of a BGR frame (640x480), with the
    setting (``mode`` "set") or without."""
    env = {
        k: v
        for k, v in os.environ.items()
        if not k.startswith("MALLOC_") and k not in ("GLIBC_TUNABLES", "LD_PRELOAD")
    }
    env["NUMPY_MADVISE_HUGEPAGE"] = "0"  # what is measured is malloc's, not the kernel's
    res = subprocess.run(
        [sys.executable, "-c", CHILD.format(w=W, h=H), mode],
        capture_output=True,
        text=True,
        env=env,
    )
    assert res.returncode == 0, res.stderr
    background, frame = (int(v) for v in res.stdout.split())
    return background, frame


glibc = pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="needs glibc's malloc")


@glibc
def test_a_freed_background_goes_back_to_the_system_and_a_frame_stays_in_the_heap() -> None:
    background_kb, frame_kb = W * H * 4 // 1024, W * H * 3 // 1024
    unset, done = kept_kb("unset"), kept_kb("set")
    assert unset[0] > background_kb // 2  # glibc's own way keeps it: the test can fail
    assert done[0] < background_kb // 8
    # A frame-sized block is reused from the heap, not mapped and faulted in for each frame
    # (which a threshold at glibc's 128 KiB, fixed, would do).
    assert done[1] > frame_kb // 2


@glibc
def test_the_threshold_is_three_and_a_half_bytes_a_pixel_within_bounds(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    for name in ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "GLIBC_TUNABLES"):
        monkeypatch.delenv(name, raising=False)
    try:
        assert separate_large_buffers(W, H) == W * H * 7 // 2
        assert separate_large_buffers(64, 48) == MIN_MMAP_THRESHOLD  # never below glibc's own
        monkeypatch.setenv("GLIBC_TUNABLES", "glibc.pthread.rseq=0")  # not malloc's: set
        assert separate_large_buffers(320, 240) == 320 * 240 * 7 // 2
    finally:
        separate_large_buffers(64, 48)  # this process goes on with glibc's starting threshold


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("MALLOC_MMAP_THRESHOLD_", "131072"),
        ("MALLOC_TRIM_THRESHOLD_", "131072"),
        ("GLIBC_TUNABLES", "glibc.malloc.mmap_threshold=131072"),
    ],
)
def test_an_environment_that_tunes_malloc_is_left_alone(
    monkeypatch: pytest.MonkeyPatch, name: str, value: str
) -> None:
    monkeypatch.setenv(name, value)
    assert separate_large_buffers(W, H) is None


def test_a_frame_size_must_be_positive() -> None:
    with pytest.raises(ValueError, match="frame size must be positive, got 0x480"):
        separate_large_buffers(0, 480)


SMAPS = """\
7f0000000000-7f0000100000 r-xp 00000000 08:01 11 /venv/cv2/cv2.abi3.so
Rss:                 800 kB
Anonymous:             0 kB
7f0000100000-7f0000110000 r--p 00100000 08:01 11 /venv/cv2/cv2.abi3.so
Rss:                  64 kB
Anonymous:            64 kB
7f0000110000-7f0000120000 rw-p 00110000 08:01 11 /venv/cv2/cv2.abi3.so
Rss:                  64 kB
Anonymous:            64 kB
7f0000200000-7f0000300000 r--p 00000000 08:01 12 /usr/lib/libc.so.6
Rss:                 120 kB
Anonymous:             0 kB
7f0000300000-7f0000400000 r--p 00000000 08:01 13 /usr/share/locale/archive
Rss:                 500 kB
Anonymous:             0 kB
7f0000400000-7f0000500000 rw-p 00000000 00:00 0 [heap]
Rss:                1000 kB
Anonymous:          1000 kB
"""


def test_only_library_pages_that_are_all_the_file_s_are_released() -> None:
    """A library's code and read-only data are taken; its relocated read-only segment (a
    private copy: unmapping it would lose the relocations), its writable data, other files
    and anonymous memory are not."""
    from stereod.daemon.memory import library_mappings

    assert library_mappings(SMAPS) == [
        (0x7F0000000000, 0x7F0000100000, 800, "/venv/cv2/cv2.abi3.so"),
        (0x7F0000200000, 0x7F0000300000, 120, "/usr/lib/libc.so.6"),
    ]


RELEASE_CHILD = """
import numpy as np, cv2
from stereod.daemon.memory import library_mappings, release_library_pages
def libraries_kb():
    return sum(m.rss_kb for m in library_mappings(open("/proc/self/smaps").read()))
rng = np.random.default_rng(1)
img = rng.integers(0, 255, (240, 320, 3), np.uint8)
def work():
    grey = cv2.cvtColor(cv2.GaussianBlur(img, (5, 5), 0), cv2.COLOR_BGR2GRAY)
    return cv2.findContours(cv2.threshold(grey, 128, 255, 0)[1], 0, 2)[0]
before = work()
mapped = libraries_kb()
released = release_library_pages()
after = work()
same = len(before) == len(after) and all((a == b).all() for a, b in zip(before, after))
print(mapped, released, libraries_kb(), same)
"""


@pytest.mark.skipif(not os.path.exists("/proc/self/smaps"), reason="needs Linux's /proc")
def test_released_library_pages_leave_the_process_working_on_what_it_uses() -> None:
    """In a process that loaded NumPy and OpenCV and ran them: release unmaps most of their
    resident pages, and the same OpenCV calls then give the same result, mapping back only
    a small part of what was released."""
    res = subprocess.run(
        [sys.executable, "-c", RELEASE_CHILD], capture_output=True, text=True, timeout=120
    )
    assert res.returncode == 0, res.stderr
    mapped, released, after, same = res.stdout.split()
    assert same == "True"
    assert int(released) > 0.8 * int(mapped) > 0
    assert int(after) < 0.5 * int(mapped)


def _cached_fraction(path: str) -> float:
    """The share of ``path``'s pages in the page cache: mincore(2) on a mapping of it."""
    import ctypes
    import mmap

    libc = ctypes.CDLL(None, use_errno=True)
    libc.mmap.argtypes = (ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int, ctypes.c_int,
                          ctypes.c_int, ctypes.c_long)  # fmt: skip
    libc.mmap.restype = ctypes.c_void_p
    libc.mincore.argtypes = (ctypes.c_void_p, ctypes.c_size_t, ctypes.c_void_p)
    libc.munmap.argtypes = (ctypes.c_void_p, ctypes.c_size_t)
    size = os.path.getsize(path)
    pages = -(-size // mmap.PAGESIZE)
    vec = (ctypes.c_ubyte * pages)()
    fd = os.open(path, os.O_RDONLY)
    try:
        addr = libc.mmap(None, size, mmap.PROT_READ, mmap.MAP_SHARED, fd, 0)
        assert addr not in (None, ctypes.c_void_p(-1).value), ctypes.get_errno()
        try:
            assert libc.mincore(addr, size, vec) == 0, ctypes.get_errno()
        finally:
            libc.munmap(addr, size)
    finally:
        os.close(fd)
    return sum(b & 1 for b in vec) / pages


def _filesystem(path: Path) -> str:
    """The type of the file system ``path`` is on (the longest mount point above it)."""
    best, kind = "", ""
    with open("/proc/self/mounts") as fh:
        for line in fh:
            _, point, fstype, *_ = line.split()
            if str(path.resolve()).startswith(point.rstrip("/") + "/") and len(point) > len(best):
                best, kind = point, fstype
    return kind


@pytest.mark.skipif(not os.path.exists("/proc/self/smaps"), reason="needs Linux's /proc")
def test_a_file_no_process_maps_leaves_the_page_cache(tmp_path: Path) -> None:
    """After it was read, a file's pages are in the cache; once dropped, (almost) none are
    (a page another process maps would stay; nothing maps this one)."""
    from stereod.daemon.memory import drop_cached_pages

    if _filesystem(tmp_path) in ("tmpfs", "ramfs"):
        pytest.skip("the temporary folder is in memory: its pages are not a cache")
    path = tmp_path / "lib.so"
    path.write_bytes(os.urandom(4 << 20))
    os.sync()  # dirty pages are not dropped: written out first
    path.read_bytes()
    assert _cached_fraction(str(path)) > 0.9
    assert drop_cached_pages(str(path))
    assert _cached_fraction(str(path)) < 0.1


def test_a_file_that_is_not_there_is_no_error(tmp_path: Path) -> None:
    from stereod.daemon.memory import drop_cached_pages

    assert not drop_cached_pages(str(tmp_path / "gone.so"))
