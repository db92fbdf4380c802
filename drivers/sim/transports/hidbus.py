"""A stand-in for the `hid` module (cython-hidapi) with simulated USB HID chips plugged in, on the
simulated clock: what the MCP2221A and CP2112 transports open instead of the real module.

    usb = FakeHid(clock)
    usb.plug(MCP2221ASim(wire, serial="0001234567"))
    usb.enumerate(0x04D8, 0x00DD)      # -> [{"path": ..., "vendor_id": 0x04D8, "serial_number": ...}]
    dev = usb.device(); dev.open(0x04D8, 0x00DD, "0001234567")
    dev.write([0x00, 0x10] + [0] * 63) # report number 0 (unnumbered reports), then the 64-byte report
    dev.read(64, 50)                   # -> the chip's reply, or [] after 50 ms with nothing to read
    usb.unplug(chip)                   # writes return -1, reads raise OSError, open fails

The hidapi behaviour kept (cython-hidapi hid.pyx): `open` and `open_path` raise OSError("open failed"),
`write` returns the byte count or -1, `read` returns a list (empty on timeout) and raises
OSError("read error"), a closed device raises ValueError("not open"), `get_feature_report` returns the
report with its number first. With unnumbered reports (the MCP2221A) the first byte written is the
report number 0 and reads carry no number (Linux hidraw.rst); with numbered ones (the CP2112) byte 0 is
the report ID both ways. A read without a timeout blocks until a report arrives: with nothing queued that
is forever, so the simulator raises instead of hanging.

Time: a full-speed HID interrupt endpoint is polled once per 1 ms frame, so every OUT report and every
IN report a read takes costs one frame on the clock; a read that finds nothing waits its timeout.
A chip implements `on_report(report) -> [replies]`, and for feature reports `on_set_feature(report)`
and `on_get_feature(report_id) -> bytes`, plus the descriptor strings below.
"""

from __future__ import annotations

from collections import deque
from typing import Any

from drivers.clock import Clock

FRAME_S = 0.001  # full-speed interrupt endpoints are polled every 1 ms frame


class FakeHid:
    """Module-like: `enumerate(vendor_id=0, product_id=0)` and `device()`, as the `hid` module has."""

    def __init__(self, clock: Clock):
        self.clock = clock
        self.chips: dict[bytes, Any] = {}  # path -> chip, plugged in
        self._next_path = 1

    def plug(self, chip) -> bytes:
        path = f"sim-hid-{self._next_path}".encode()
        self._next_path += 1
        chip.path = path
        self.replug(chip)
        return path

    def unplug(self, chip) -> None:
        self.chips.pop(chip.path, None)

    def replug(self, chip) -> None:
        """Plug the same chip back in: it powers up afresh, at the same path; handles opened before
        stay dead (the device enumerated anew)."""
        self.chips[chip.path] = chip
        chip.power_ups = getattr(chip, "power_ups", 0) + 1
        chip.power_on()

    def enumerate(self, vendor_id: int = 0, product_id: int = 0) -> list[dict]:
        return [_info(chip) for chip in self.chips.values()
                if vendor_id in (0, chip.vendor_id) and product_id in (0, chip.product_id)]

    def device(self) -> FakeHidDevice:
        return FakeHidDevice(self)


def _info(chip) -> dict:
    return {"path": chip.path, "vendor_id": chip.vendor_id, "product_id": chip.product_id,
            "serial_number": chip.serial_number, "release_number": chip.release_number,
            "manufacturer_string": chip.manufacturer, "product_string": chip.product,
            "usage_page": 0xFF00, "usage": 1, "interface_number": chip.hid_interface}


class FakeHidDevice:
    def __init__(self, usb: FakeHid):
        self.usb = usb
        self.chip = None
        self.power_up = 0  # which power-up of the chip this handle was opened on
        self.replies: deque[bytes] = deque()

    # --- opening ------------------------------------------------------------------------------------
    def open(self, vendor_id: int = 0, product_id: int = 0, serial_number: str | None = None) -> None:
        for info in self.usb.enumerate(vendor_id, product_id):
            if serial_number is None or info["serial_number"] == serial_number:
                return self.open_path(info["path"])
        raise OSError("open failed")

    def open_path(self, path: bytes) -> None:
        chip = self.usb.chips.get(path)
        if chip is None:
            raise OSError("open failed")
        self.chip = chip
        self.power_up = chip.power_ups
        self.replies = deque(chip.on_open())

    def close(self) -> None:
        self.chip = None

    def set_nonblocking(self, value: int) -> int:
        self._open_chip()
        return 0

    # --- reports ------------------------------------------------------------------------------------
    def write(self, buff) -> int:
        chip = self._open_chip()
        data = bytes(buff)
        if not self._present(chip):
            return -1
        report = data if chip.numbered_reports else data[1:]
        if not chip.numbered_reports and (data[:1] != b"\x00" or len(report) != chip.report_length):
            return -1  # not report number 0 and one whole report: the device never sees it
        self.usb.clock.sleep(FRAME_S)
        self.replies.extend(chip.on_report(report))
        return len(data)

    def read(self, max_length: int, timeout_ms: int = 0) -> list[int]:
        chip = self._open_chip()
        if not self._present(chip):
            raise OSError("read error")
        if self.replies:
            self.usb.clock.sleep(FRAME_S)
            return list(self.replies.popleft()[:max_length])
        if timeout_ms <= 0:
            raise RuntimeError("hid read without a timeout and nothing to read: it would block forever")
        self.usb.clock.sleep(timeout_ms / 1000)
        return []

    def send_feature_report(self, buff) -> int:
        chip = self._open_chip()
        if not self._present(chip):
            return -1
        self.usb.clock.sleep(FRAME_S)
        return len(buff) if chip.on_set_feature(bytes(buff)) else -1

    def get_feature_report(self, report_num: int, max_length: int) -> list[int]:
        chip = self._open_chip()
        if not self._present(chip):
            raise OSError("read error")
        self.usb.clock.sleep(FRAME_S)
        report = chip.on_get_feature(report_num)
        if report is None:
            raise OSError("read error")
        return list(report[:max_length])

    # --- strings ------------------------------------------------------------------------------------
    def get_serial_number_string(self) -> str:
        return self._open_chip().serial_number

    def get_product_string(self) -> str:
        return self._open_chip().product

    def get_manufacturer_string(self) -> str:
        return self._open_chip().manufacturer

    def _open_chip(self):
        if self.chip is None:
            raise ValueError("not open")
        return self.chip

    def _present(self, chip) -> bool:
        return self.usb.chips.get(chip.path) is chip and chip.power_ups == self.power_up
