"""A fake pyusb backend: USB devices with the descriptors a Minoru's eyes have, and a record
of the resets asked for. Lets discovery and reset be tested without hardware or libusb."""

from __future__ import annotations

from dataclasses import dataclass

import usb.backend


@dataclass
class FakeUsbDevice:
    """One device as pyusb's backend describes it (speed: usb.util.SPEED_*; 3 is high)."""

    idVendor: int
    idProduct: int
    bus: int
    address: int
    ports: tuple[int, ...]
    speed: int = 3
    bLength: int = 18
    bDescriptorType: int = 1
    bcdUSB: int = 0x0200
    bDeviceClass: int = 0xEF
    bDeviceSubClass: int = 2
    bDeviceProtocol: int = 1
    bMaxPacketSize0: int = 64
    bcdDevice: int = 0x0100
    iManufacturer: int = 0
    iProduct: int = 0
    iSerialNumber: int = 0
    bNumConfigurations: int = 1

    @property
    def port_number(self) -> int:
        return self.ports[-1]

    @property
    def port_numbers(self) -> tuple[int, ...]:
        return self.ports


class FakeBackend(usb.backend.IBackend):
    """Enumerates the given devices; ``resets`` lists the addresses reset, in order."""

    def __init__(self, devices: list[FakeUsbDevice]) -> None:
        self.devices = devices
        self.resets: list[int] = []

    def enumerate_devices(self) -> list[FakeUsbDevice]:
        return list(self.devices)

    def get_device_descriptor(self, dev: FakeUsbDevice) -> FakeUsbDevice:
        return dev

    def open_device(self, dev: FakeUsbDevice) -> FakeUsbDevice:
        return dev

    def close_device(self, dev_handle: FakeUsbDevice) -> None:
        return None

    def reset_device(self, dev_handle: FakeUsbDevice) -> None:
        self.resets.append(dev_handle.address)
