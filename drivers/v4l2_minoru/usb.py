"""USB side of the Minoru eyes through pyusb: descriptors (ids, speed) and reset.

A wedged UVC camera often streams again after a USB reset, which is what ``stereod devices
--reset EYE`` does. The pyusb backend is injectable, so tests run against a fake one.
"""

from __future__ import annotations

from typing import Any

from stereod.errors import DeviceError

SPEEDS_MBPS = {1: 1.5, 2: 12.0, 3: 480.0, 4: 5000.0, 5: 10000.0}
"""pyusb's speed constants (usb.util.SPEED_*) in Mbit/s."""


def find_usb(bus: int, address: int, backend: Any = None) -> Any:
    """The pyusb device at ``bus``/``address``; DeviceError when pyusb or the device is absent."""
    try:
        import usb.core
    except ImportError as exc:
        raise DeviceError("pyusb is not installed (pip install pyusb)") from exc
    try:
        dev = usb.core.find(bus=bus, address=address, backend=backend)
    except usb.core.NoBackendError as exc:
        raise DeviceError("no libusb backend for pyusb: install libusb-1.0") from exc
    if dev is None:
        raise DeviceError(f"no USB device at bus {bus} address {address}")
    return dev


def describe(dev: Any) -> dict[str, Any]:
    """Vendor and product ids (hex), port path and speed (Mbit/s) of a pyusb device."""
    ports = getattr(dev, "port_numbers", None) or ()
    return {
        "vendor": f"{dev.idVendor:04x}",
        "product": f"{dev.idProduct:04x}",
        "bus": dev.bus,
        "address": dev.address,
        "port_path": f"{dev.bus}-" + ".".join(str(p) for p in ports) if ports else str(dev.bus),
        "speed_mbps": SPEEDS_MBPS.get(getattr(dev, "speed", 0) or 0),
    }


def reset(bus: int, address: int, backend: Any = None) -> None:
    """USB-reset the device at ``bus``/``address``."""
    dev = find_usb(bus, address, backend)
    try:
        dev.reset()
    except Exception as exc:  # pyusb raises USBError and backend-specific errors
        raise DeviceError(f"USB reset of bus {bus} address {address} failed: {exc}") from exc
