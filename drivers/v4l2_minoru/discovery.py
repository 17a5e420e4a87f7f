"""Find video capture nodes in sysfs and tell which is a Minoru eye, and which eye.

Each Minoru eye is a Vimicro UVC camera (0ac8:3410 or 0ac8:3420) without a serial number, so
the eyes differ only by the port of the Minoru's internal hub: port 1 is the left eye, port 2
the right. Each eye has a capture node (sysfs ``index`` 0) and a metadata node (``index`` 1);
only capture nodes are listed.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

MINORU_IDS = {("0ac8", "3410"), ("0ac8", "3420")}
HUB_PORT_EYE = {1: "left", 2: "right"}


@dataclass(frozen=True)
class UsbInfo:
    """The USB device behind a video node, read from sysfs."""

    vendor: str
    product: str
    port_path: str
    """Kernel port path, e.g. ``1-1.2`` (bus 1, root port 1, hub port 2)."""
    speed_mbps: float | None
    busnum: int | None
    devnum: int | None
    manufacturer: str = ""
    product_name: str = ""

    @property
    def is_minoru(self) -> bool:
        return (self.vendor, self.product) in MINORU_IDS

    @property
    def hub_port(self) -> int | None:
        tail = self.port_path.rsplit(".", 1)
        return int(tail[1]) if len(tail) == 2 and tail[1].isdigit() else None


@dataclass(frozen=True)
class VideoNode:
    """One capture node: ``/dev/videoN``, its name, and its USB device when it has one."""

    device: str
    name: str
    usb: UsbInfo | None

    @property
    def eye(self) -> str | None:
        """``left``/``right`` for a Minoru eye (by hub port), else ``None``."""
        if self.usb is None or not self.usb.is_minoru:
            return None
        return HUB_PORT_EYE.get(self.usb.hub_port or 0)


def _read(path: Path) -> str:
    try:
        return path.read_text().strip()
    except OSError:
        return ""


def _usb_device_dir(dev: Path) -> Path | None:
    """The USB device folder (with idVendor) above a video node's device link."""
    for d in [dev, *dev.parents]:
        if (d / "idVendor").is_file():
            return d
        if d.name in ("", "devices", "/"):
            break
    return None


def _number(text: str) -> int | None:
    return int(text) if text.isdigit() else None


def find_nodes(sysfs: Path = Path("/sys"), dev_root: Path = Path("/dev")) -> list[VideoNode]:
    """Every capture node (``index`` 0) under ``sysfs``/class/video4linux, sorted by name."""
    base = sysfs / "class" / "video4linux"
    if not base.is_dir():
        return []
    nodes = []
    for entry in sorted(base.iterdir(), key=lambda p: (len(p.name), p.name)):
        if _read(entry / "index") not in ("", "0"):
            continue
        usb = None
        device_link = entry / "device"
        if device_link.exists():
            d = _usb_device_dir(device_link.resolve())
            if d is not None:
                speed = _read(d / "speed")
                usb = UsbInfo(
                    vendor=_read(d / "idVendor"),
                    product=_read(d / "idProduct"),
                    port_path=d.name,
                    speed_mbps=float(speed) if speed.replace(".", "", 1).isdigit() else None,
                    busnum=_number(_read(d / "busnum")),
                    devnum=_number(_read(d / "devnum")),
                    manufacturer=_read(d / "manufacturer"),
                    product_name=_read(d / "product"),
                )
        nodes.append(VideoNode(str(dev_root / entry.name), _read(entry / "name"), usb))
    return nodes


def minoru_eyes(nodes: list[VideoNode]) -> dict[str, str]:
    """``{"left": "/dev/videoN", "right": ...}`` for the Minoru eyes found."""
    return {n.eye: n.device for n in nodes if n.eye is not None}
