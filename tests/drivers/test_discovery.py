"""sysfs discovery on fixture trees built like the kernel's, and pyusb through a fake backend."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from stereod.errors import DeviceError
from stereod_fakes.usb import FakeBackend, FakeUsbDevice
from stereod_v4l2_minoru.discovery import find_nodes, minoru_eyes
from stereod_v4l2_minoru.usb import describe, find_usb, reset


def make_usb_node(sysfs: Path, video: str, port: str, product: str, index: int, name: str) -> None:
    usbdev = sysfs / "devices/pci0000:00/0000:00:14.0/usb1" / "1-1" / port
    usbdev.mkdir(parents=True, exist_ok=True)
    for k, v in {
        "idVendor": "0ac8",
        "idProduct": product,
        "speed": "480",
        "busnum": "1",
        "devnum": port.rsplit(".", 1)[-1] + "0",
        "manufacturer": "Vimicro",
    }.items():
        (usbdev / k).write_text(v + "\n")
    iface = usbdev / f"{port}:1.0"
    iface.mkdir(exist_ok=True)
    cls = sysfs / "class/video4linux" / video
    cls.mkdir(parents=True)
    (cls / "index").write_text(f"{index}\n")
    (cls / "name").write_text(name + "\n")
    os.symlink(iface, cls / "device")


def test_minoru_eyes_by_hub_port(tmp_path: Path) -> None:
    make_usb_node(tmp_path, "video0", "1-1.2", "3420", 0, "Vimicro USB Camera (Altair)")
    make_usb_node(tmp_path, "video1", "1-1.2", "3420", 1, "Vimicro USB Camera (Altair)")
    make_usb_node(tmp_path, "video2", "1-1.1", "3410", 0, "Vimicro USB Camera (Altair)")
    make_usb_node(tmp_path, "video3", "1-1.1", "3410", 1, "Vimicro USB Camera (Altair)")
    nodes = find_nodes(tmp_path, Path("/dev"))
    assert [n.device for n in nodes] == ["/dev/video0", "/dev/video2"]  # metadata nodes skipped
    assert minoru_eyes(nodes) == {"left": "/dev/video2", "right": "/dev/video0"}
    usb = nodes[0].usb
    assert usb is not None and usb.speed_mbps == 480.0 and usb.port_path == "1-1.2"
    assert usb.is_minoru and usb.hub_port == 2


def test_no_video4linux(tmp_path: Path) -> None:
    assert find_nodes(tmp_path) == []


def test_non_usb_node_has_no_eye(tmp_path: Path) -> None:
    cls = tmp_path / "class/video4linux/video0"
    cls.mkdir(parents=True)
    (cls / "index").write_text("0\n")
    (cls / "name").write_text("vivid-000-vid-cap\n")
    (tmp_path / "devices/platform/vivid.0").mkdir(parents=True)
    os.symlink(tmp_path / "devices/platform/vivid.0", cls / "device")
    [node] = find_nodes(tmp_path)
    assert node.usb is None and node.eye is None and node.name == "vivid-000-vid-cap"


def test_pyusb_descriptors_and_reset_through_fake_backend() -> None:
    left = FakeUsbDevice(0x0AC8, 0x3410, bus=1, address=10, ports=(1, 1), speed=3)
    right = FakeUsbDevice(0x0AC8, 0x3420, bus=1, address=20, ports=(1, 2), speed=3)
    backend = FakeBackend([left, right])
    d = describe(find_usb(1, 20, backend))
    assert d == {
        "vendor": "0ac8",
        "product": "3420",
        "bus": 1,
        "address": 20,
        "port_path": "1-1.2",
        "speed_mbps": 480.0,
    }
    reset(1, 10, backend)
    assert backend.resets == [10]
    with pytest.raises(DeviceError, match="no USB device at bus 1 address 99"):
        find_usb(1, 99, backend)
