"""What the two HID bridges (MCP2221A, CP2112) share: finding and opening the device through hidapi (the
`hid` module, imported only when such a bridge is opened), and reading and writing its reports with the
errors every bridge gives (drivers/transports/bridge.py).

    dev, info = open_hid(hid_module, 0x04D8, 0x00DD, serial, name="mcp2221 0001234567", model="MCP2221A")
    link = HidLink(dev, bus)          # bus: the BridgeBus, for its name, clock and frame log
    link.write(report); link.read(timeout_ms, expect=0x10)
"""

from __future__ import annotations

from typing import Any

from drivers.errors import DeviceError, DeviceNotFound, DeviceTimeout, ProtocolError


def import_hid(name: str) -> Any:
    try:
        import hid  # cython-hidapi: only a station with a HID bridge needs it
    except ImportError as exc:
        raise DeviceNotFound(name, "open", "the hidapi package is not installed "
                                           "(pip install 'magrig[bridges]')") from exc
    return hid


def usb_id(vendor_id: int, product_id: int) -> str:
    return f"{vendor_id:04x}:{product_id:04x}"


def open_hid(hid: Any, vendor_id: int, product_id: int, serial: str | None, *, name: str,
             model: str) -> tuple[Any, dict]:
    """Open the bridge with this serial number (None: the only one plugged in). DeviceNotFound names
    what was looked for and what is there."""
    found = hid.enumerate(vendor_id, product_id)
    serials = sorted({str(d.get("serial_number") or "?") for d in found})
    matching = [d for d in found if serial is None or d.get("serial_number") == serial]
    wanted = f"{model} (USB {usb_id(vendor_id, product_id)})"
    if not matching:
        where = f" with serial number {serial}" if serial is not None else ""
        there = f" (plugged in: serial numbers {', '.join(serials)})" if found else ""
        raise DeviceNotFound(name, "open", f"no {wanted}{where} is plugged in{there}")
    if serial is None and len({d.get("serial_number") for d in matching}) > 1:
        raise DeviceError(name, "open", f"{len(serials)} {wanted} are plugged in (serial numbers "
                                        f"{', '.join(serials)}): name one with `serial:`")
    info = matching[0]
    dev = hid.device()
    try:
        dev.open_path(info["path"])
    except OSError as exc:
        raise DeviceNotFound(name, "open", f"{wanted} serial number {info.get('serial_number')} is there but "
                                           "cannot be opened (in use, a kernel driver bound to it, or no "
                                           "permission: docs/bus-scan.md)") from exc
    return dev, info


class HidLink:
    """Reports to and from one opened HID bridge. USB failures become DeviceNotFound ("gone"), a missing
    reply DeviceTimeout, a reply to another command ProtocolError, all naming the bridge."""

    def __init__(self, dev: Any, bus):
        self.dev = dev
        self.bus = bus
        self.gone = False

    def write(self, report: bytes) -> None:
        self.bus.log_frame("tx", report)
        try:
            written = self.dev.write(report)
        except (OSError, ValueError) as exc:
            written = -1
            self.bus.frame_log.debug("%s: write failed: %s", self.bus.name, exc)
        if written < 0:
            self.gone = True
            raise DeviceNotFound(self.bus.name, "USB write", "the bridge does not take reports (unplugged?)")

    def read(self, length: int, timeout_ms: int, expect: int | tuple[int, ...]) -> bytes:
        """The next IN report, which must start with `expect` (a command echo or a report ID)."""
        try:
            reply = bytes(self.dev.read(length, timeout_ms))
        except (OSError, ValueError) as exc:
            self.gone = True
            detail = "the bridge does not answer (unplugged?)"
            raise DeviceNotFound(self.bus.name, "USB read", detail) from exc
        if not reply:
            raise DeviceTimeout(self.bus.name, "USB read", f"no reply within {timeout_ms} ms")
        self.bus.log_frame("rx", reply)
        expected = (expect,) if isinstance(expect, int) else expect
        if reply[0] not in expected:
            raise ProtocolError(self.bus.name, "USB read", f"reply 0x{reply[0]:02X} where "
                                + " or ".join(f"0x{e:02X}" for e in expected) + " belongs")
        return reply

    def close(self) -> None:
        try:
            self.dev.close()
        except (OSError, ValueError):
            pass
