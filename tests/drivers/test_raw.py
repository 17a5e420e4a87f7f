"""Struct sizes and ioctl numbers against the kernel's own header, compiled with the C compiler."""

from __future__ import annotations

import ctypes
import shutil
import subprocess
from pathlib import Path

import pytest

from stereod_v4l2_minoru import raw

HEADER = Path("/usr/include/linux/videodev2.h")


@pytest.fixture(scope="module")
def kernel_abi(tmp_path_factory: pytest.TempPathFactory) -> dict[str, int]:
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None or not HEADER.exists():
        pytest.skip("needs a C compiler and linux/videodev2.h (linux-libc-dev)")
    d = tmp_path_factory.mktemp("abi")
    lines = [f'printf("{n} %zu\\n", sizeof(struct {n}));' for n in raw.STRUCTS]
    lines += [f'printf("{n} %lu\\n", (unsigned long){n});' for n in raw.REQUESTS]
    (d / "abi.c").write_text(
        "#include <stdio.h>\n#include <linux/videodev2.h>\nint main(void){\n"
        + "\n".join(lines)
        + "\nreturn 0;}\n"
    )
    subprocess.run([cc, "-o", str(d / "abi"), str(d / "abi.c")], check=True)
    out = subprocess.run([str(d / "abi")], capture_output=True, text=True, check=True).stdout
    return {k: int(v) for k, v in (line.split() for line in out.splitlines())}


@pytest.mark.parametrize("name", sorted(raw.STRUCTS))
def test_struct_size_matches_kernel(kernel_abi: dict[str, int], name: str) -> None:
    assert ctypes.sizeof(raw.STRUCTS[name]) == kernel_abi[name]


@pytest.mark.parametrize("name", sorted(raw.REQUESTS))
def test_ioctl_number_matches_kernel(kernel_abi: dict[str, int], name: str) -> None:
    assert raw.REQUESTS[name] == kernel_abi[name], f"{name}: {raw.REQUESTS[name]:#x}"


def test_fourcc() -> None:
    assert raw.fourcc("YUYV") == 0x56595559
    assert raw.fourcc_str(raw.V4L2_PIX_FMT_MJPEG) == "MJPG"
