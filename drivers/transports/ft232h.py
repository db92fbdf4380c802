"""FTDI FT232H USB-to-I2C through pyftdi's I2cController (MPSSE, hardware-notes 8.3), under the smbus2
methods the drivers use (drivers/transports/bridge.py).

    bus = FT232HBus("ftdi://ftdi:232h/1", speed_hz=100_000, clock=clock)   # usb_backend: a stand-in

The URL names the device as pyftdi's do: ftdi://[vendor][:product[:serial|:index]]/interface, e.g.
ftdi://ftdi:232h/1, ftdi://ftdi:232h:FT0FMF6V/1, ftdi://::FT0FMF6V/1. It is looked up through pyusb (the
default backend, libusb, or the one given) and the USB device handed to I2cController.configure, with
the bus frequency and the latency timer. pyftdi's own NACK retries are set to 1: the project's policy
retries above. A register read is `exchange()` (START, address, register, repeated START, read, STOP),
a write `write()`, a quick write `poll()`. NACK (I2cNackError) is OSError 121; "No answer from FTDI"
(I2cIOError) a timeout; a USB error (FtdiError, USBError) a device gone. The FT232H drives the pins and
samples them, so a bus held low looks like ACKs and zero bytes: after every write, quick write or
all-zero read the pins are read back (MPSSE 0x81), and SDA or SCL low is reported as a stuck bus.

The latency timer (ms, default pyftdi's 16) is how long the chip holds a reply that was not flushed, and
pyftdi's STOP waits for one such reply: it sets the time of every transfer (bench/bridges.py).
"""

from __future__ import annotations

import logging
from typing import Any
from urllib.parse import urlsplit

from drivers.clock import Clock
from drivers.errors import DeviceNotFound, DeviceTimeout
from drivers.transports.bridge import TRIES, BridgeBus, check_speed, nack_error

FTDI_VENDOR_ID = 0x0403
FT232H_PRODUCT_ID = 0x6014
VENDORS = {"ftdi": FTDI_VENDOR_ID}
PRODUCTS = {"232h": FT232H_PRODUCT_ID, "ft232h": FT232H_PRODUCT_ID}
GET_BITS_LOW, SEND_IMMEDIATE = 0x81, 0x87
SCL, SDA_IN = 0x01, 0x04
DEFAULT_URL = "ftdi://ftdi:232h/1"
LATENCY_MS = 16  # pyftdi's default


def _number(text: str, names: dict[str, int], what: str, url: str) -> int | None:
    if not text:
        return None
    if text.lower() in names:
        return names[text.lower()]
    try:
        return int(text, 16 if text.lower().startswith("0x") else 10)
    except ValueError:
        raise ValueError(f"{url}: unknown {what} {text!r}") from None


def parse_url(url: str) -> tuple[int, int, str | None, int, int]:
    """(vendor id, product id, serial or None, index, interface) of an ftdi:// URL."""
    parts = urlsplit(url)
    if parts.scheme != "ftdi" or not parts.path.strip("/"):
        raise ValueError(f"{url}: not an ftdi://[vendor][:product[:serial|:index]]/interface URL")
    fields = (parts.netloc.split(":") + ["", "", ""])[:3]
    vendor = _number(fields[0], VENDORS, "vendor", url) or FTDI_VENDOR_ID
    product = _number(fields[1], PRODUCTS, "product", url) or FT232H_PRODUCT_ID
    if fields[2].isdigit() and len(fields[2]) < 3:  # a small number is an index, as pyftdi reads it
        serial, index = None, int(fields[2])
    else:
        serial, index = fields[2] or None, 0
    return vendor, product, serial, index, int(parts.path.strip("/"))


def list_devices(usb_backend: Any = None) -> list[dict]:
    """The FT232H devices plugged in: {vendor_id, product_id, serial_number, bus, address}."""
    import usb.core
    import usb.util

    out = []
    for dev in usb.core.find(find_all=True, idVendor=FTDI_VENDOR_ID, idProduct=FT232H_PRODUCT_ID,
                             backend=usb_backend):
        try:
            serial = usb.util.get_string(dev, dev.iSerialNumber) if dev.iSerialNumber else None
        except (usb.core.USBError, ValueError):
            serial = None  # no permission to read the strings
        out.append({"vendor_id": dev.idVendor, "product_id": dev.idProduct, "serial_number": serial,
                    "bus": dev.bus, "address": dev.address, "device": dev})
    return out


class FT232HBus(BridgeBus):
    kind = "ft232h"

    def __init__(self, url: str = DEFAULT_URL, *, speed_hz: float = 100_000, clock: Clock | None = None,
                 tries: int = TRIES, latency_ms: int = LATENCY_MS, usb_backend: Any = None):
        super().__init__(f"ft232h {url}", clock=clock, tries=tries)
        check_speed(self.kind, speed_hz)
        self.url = url
        self.speed_hz = speed_hz
        self.latency_ms = latency_ms
        self.usb_backend = usb_backend
        self.controller = None
        self.gone = False
        self._open()

    # --- opening ------------------------------------------------------------------------------------
    def _open(self) -> None:
        try:
            from pyftdi.ftdi import FtdiError
            from pyftdi.i2c import I2cController
        except ImportError as exc:
            raise DeviceNotFound(self.name, "open", "the pyftdi package is not installed "
                                                    "(pip install 'magrig[bridges]')") from exc
        pyftdi_log = logging.getLogger("pyftdi.i2c")
        if pyftdi_log.level == logging.NOTSET:
            pyftdi_log.setLevel(logging.ERROR)  # its NACK warnings: this transport raises NACKs itself
        vendor, product, serial, index, interface = parse_url(self.url)
        found = [d for d in list_devices(self.usb_backend)
                 if (d["vendor_id"], d["product_id"]) == (vendor, product)
                 and serial in (None, d["serial_number"])]
        if len(found) <= index:
            there = ", ".join(str(d["serial_number"]) for d in list_devices(self.usb_backend))
            raise DeviceNotFound(self.name, "open", f"no FT232H (USB {vendor:04x}:{product:04x}) matches "
                                 f"{self.url}" + (f" (plugged in: serial numbers {there})" if there else ""))
        self.device = found[index]["device"]
        controller = I2cController()
        controller.set_retry_count(1)
        try:
            controller.configure(self.device, interface=interface, frequency=self.speed_hz,
                                 latency=self.latency_ms)
        except (FtdiError, OSError, ValueError) as exc:
            raise DeviceNotFound(self.name, "open", f"cannot open it as an I2C master: {exc} (in use, or no "
                                                    "permission: docs/bus-scan.md)") from exc
        self.controller, self.gone = controller, False
        self._check_lines("open")

    def close(self) -> None:
        if self.controller is not None:
            try:
                self.controller.close()
            except Exception as exc:  # noqa: BLE001 - a device already gone cannot be closed cleanly
                self.frame_log.debug("%s: close: %s", self.name, exc)
            self.controller = None
            import usb.util

            usb.util.dispose_resources(self.device)

    def _recover(self) -> None:
        if self.controller is None or self.gone:
            self.close()
            self._open()

    # --- transfers ----------------------------------------------------------------------------------
    def _transfer(self, address: int, write: bytes, read_length: int) -> bytes:
        from pyftdi.ftdi import FtdiError
        from pyftdi.i2c import I2cIOError, I2cNackError
        from usb.core import USBError

        if self.controller is None:
            self._open()  # closed after a USB failure: it must be back to go on
        self.log_frame("tx", bytes([address << 1 | bool(read_length and not write)]) + write)
        try:
            if read_length and write:
                data = bytes(self.controller.exchange(address, write, read_length))
            elif read_length:
                data = bytes(self.controller.read(address, read_length))
            elif write:
                self.controller.write(address, write)
                data = b""
            elif not self.controller.poll(address, write=True):
                raise nack_error()
            else:
                data = b""
        except I2cNackError:
            raise nack_error() from None
        except I2cIOError as exc:
            raise DeviceTimeout(self.name, "I2C transfer", f"{exc} (the MPSSE did not answer)") from exc
        except (FtdiError, USBError) as exc:
            self.gone = True
            raise DeviceNotFound(self.name, "I2C transfer", f"USB: {exc} (unplugged?)") from exc
        self.log_frame("rx", data)
        if not any(data):
            self._check_lines("I2C transfer")
        return data

    def write_quick(self, i2c_addr: int, force: bool | None = None) -> None:
        """SMBus quick command: START, the address with W, STOP; only the ACK tells (bus scans)."""
        self.transfer(i2c_addr, b"", 0, "quick write")

    def _check_lines(self, operation: str) -> None:
        """Read the pins: with the bus idle, SCL and SDA must both be high."""
        from pyftdi.ftdi import FtdiError

        ftdi = self.controller.ftdi
        try:
            ftdi.write_data(bytes([GET_BITS_LOW, SEND_IMMEDIATE]))
            pins = ftdi.read_data_bytes(1, 4)
        except FtdiError as exc:
            self.gone = True
            raise DeviceNotFound(self.name, operation, f"USB: {exc} (unplugged?)") from exc
        if not pins:
            raise DeviceTimeout(self.name, operation, "no answer from the MPSSE reading the pins")
        low = [name for name, bit in (("SCL", SCL), ("SDA", SDA_IN)) if not pins[0] & bit]
        if low:
            raise DeviceTimeout(self.name, operation, f"bus stuck: {' and '.join(low)} held low")
