"""A pyusb backend with simulated USB devices plugged in: what pyftdi (and so the FT232H transport) talks
to instead of libusb, one USB request at a time. The devices are the simulators
(drivers/sim/transports/ft232h.py): each gives its descriptors and answers vendor control requests and bulk
transfers as the chip does.

    backend = FakeUsbBackend()
    backend.plug(FT232HSim(wire, clock, serial="FT0SIM01"))
    usb.core.find(find_all=True, idVendor=0x0403, backend=backend)   # real pyusb Device objects
    backend.unplug(device)                                             # every request: USBError errno 19

The backend answers the standard requests a host makes of any device: the descriptors (device, one
configuration, its interfaces and endpoints, the string descriptors in US English) and the configuration
value; vendor requests and bulk transfers go to the device (`control_out`, `control_in`, `bulk_out`,
`bulk_in`). Interrupt and isochronous transfers are not modelled.
"""

from __future__ import annotations

import errno
from types import SimpleNamespace

from usb.backend import IBackend
from usb.core import USBError

GET_DESCRIPTOR = 0x06
STRING_DESCRIPTOR = 0x03
LANGUAGE_EN_US = 0x0409
REQUEST_TYPE_MASK = 0x60
STANDARD, VENDOR = 0x00, 0x40
DIRECTION_IN = 0x80


def _gone() -> USBError:
    return USBError("No such device (it may have been disconnected)", errno=errno.ENODEV)


class FakeUsbBackend(IBackend):
    def __init__(self) -> None:
        super().__init__()
        self.devices: list = []  # plugged in
        self._bus_addresses = 0

    def plug(self, device) -> None:
        if device not in self.devices:
            self._bus_addresses += 1
            device.address = self._bus_addresses
            self.devices.append(device)
        device.power_on()

    def unplug(self, device) -> None:
        if device in self.devices:
            self.devices.remove(device)

    def _present(self, handle) -> object:
        if handle.device not in self.devices:
            raise _gone()
        return handle.device

    # --- descriptors --------------------------------------------------------------------------------
    def enumerate_devices(self):
        return list(self.devices)

    def get_device_descriptor(self, dev):
        strings = dev.strings()
        return SimpleNamespace(
            bLength=18, bDescriptorType=1, bcdUSB=0x0200, bDeviceClass=0, bDeviceSubClass=0,
            bDeviceProtocol=0, bMaxPacketSize0=64, idVendor=dev.vendor_id, idProduct=dev.product_id,
            bcdDevice=dev.bcd_device, iManufacturer=1 if strings[0] else 0, iProduct=2 if strings[1] else 0,
            iSerialNumber=3 if strings[2] else 0, bNumConfigurations=1, address=dev.address, bus=1,
            port_number=dev.address, port_numbers=(dev.address,), speed=dev.usb_speed)

    def get_configuration_descriptor(self, dev, config):
        if config != 0:
            raise IndexError("one configuration")
        return SimpleNamespace(bLength=9, bDescriptorType=2, wTotalLength=9 + 23 * len(dev.interfaces()),
                               bNumInterfaces=len(dev.interfaces()), bConfigurationValue=1, iConfiguration=0,
                               bmAttributes=0x80, bMaxPower=50, extra_descriptors=[])

    def get_interface_descriptor(self, dev, intf, alt, config):
        if alt != 0 or intf >= len(dev.interfaces()):
            raise IndexError("no such interface or alternate setting")
        endpoints = dev.interfaces()[intf]
        return SimpleNamespace(bLength=9, bDescriptorType=4, bInterfaceNumber=intf, bAlternateSetting=0,
                               bNumEndpoints=len(endpoints), bInterfaceClass=0xFF, bInterfaceSubClass=0xFF,
                               bInterfaceProtocol=0xFF, iInterface=2, extra_descriptors=[])

    def get_endpoint_descriptor(self, dev, ep, intf, alt, config):
        address, max_packet = dev.interfaces()[intf][ep]
        return SimpleNamespace(bLength=7, bDescriptorType=5, bEndpointAddress=address, bmAttributes=0x02,
                               wMaxPacketSize=max_packet, bInterval=0, bRefresh=0, bSynchAddress=0,
                               extra_descriptors=[])

    # --- handles ------------------------------------------------------------------------------------
    def open_device(self, dev):
        if dev not in self.devices:
            raise _gone()
        return SimpleNamespace(device=dev)

    def close_device(self, dev_handle) -> None:
        pass

    def set_configuration(self, dev_handle, config_value) -> None:
        self._present(dev_handle)

    def get_configuration(self, dev_handle) -> int:
        self._present(dev_handle)
        return 1

    def claim_interface(self, dev_handle, intf) -> None:
        self._present(dev_handle)

    def release_interface(self, dev_handle, intf) -> None:
        pass

    def is_kernel_driver_active(self, dev_handle, intf) -> bool:
        return False

    def detach_kernel_driver(self, dev_handle, intf) -> None:
        pass

    def attach_kernel_driver(self, dev_handle, intf) -> None:
        pass

    def reset_device(self, dev_handle) -> None:
        self._present(dev_handle).power_on()

    # --- transfers ----------------------------------------------------------------------------------
    def ctrl_transfer(self, dev_handle, bmRequestType, bRequest, wValue, wIndex, data, timeout):
        dev = self._present(dev_handle)
        kind = bmRequestType & REQUEST_TYPE_MASK
        if kind == STANDARD and bRequest == GET_DESCRIPTOR and wValue >> 8 == STRING_DESCRIPTOR:
            return _fill(data, _string_descriptor(dev, wValue & 0xFF))
        if kind == VENDOR and bmRequestType & DIRECTION_IN:
            return _fill(data, dev.control_in(bRequest, wValue, wIndex, len(data)))
        if kind == VENDOR:
            dev.control_out(bRequest, wValue, wIndex, bytes(data))
            return len(data)
        raise USBError("request not modelled (stall)", errno=errno.EPIPE)

    def bulk_write(self, dev_handle, ep, intf, data, timeout) -> int:
        return self._present(dev_handle).bulk_out(ep, bytes(data))

    def bulk_read(self, dev_handle, ep, intf, buff, timeout) -> int:
        return _fill(buff, self._present(dev_handle).bulk_in(ep, len(buff)))


def _string_descriptor(dev, index: int) -> bytes:
    if index == 0:
        return bytes([4, STRING_DESCRIPTOR]) + LANGUAGE_EN_US.to_bytes(2, "little")
    text = dev.strings()[index - 1].encode("utf-16-le")
    return bytes([2 + len(text), STRING_DESCRIPTOR]) + text


def _fill(buff, reply: bytes) -> int:
    n = min(len(buff), len(reply))
    buff[:n] = type(buff)(buff.typecode, reply[:n]) if hasattr(buff, "typecode") else reply[:n]
    return n
