"""Which USB-to-I2C bridges are plugged in (`rig devices scan --bridges`): MCP2221A and CP2112 by their
HID vendor and product ids, FT232H through pyftdi's listing."""

from __future__ import annotations

HID_BRIDGES = {"mcp2221": (0x04D8, 0x00DD, "MCP2221A"), "cp2112": (0x10C4, 0xEA90, "CP2112")}


def bridges_present(hid_module=None, usb_backend=None) -> tuple[list[dict], list[str]]:
    """Every MCP2221A, CP2112 and FT232H plugged in, as [{kind, model, usb_id, serial_number}], and
    notes on what could not be looked at (a package not installed, no USB access). `hid_module` and
    `usb_backend` are stand-ins for hidapi and pyusb's backend (simulations); None: the real ones."""
    found: list[dict] = []
    notes: list[str] = []
    hid = hid_module
    if hid is None:
        try:
            import hid  # noqa: F811 - cython-hidapi, only when bridges are looked for
        except ImportError:
            notes.append("MCP2221A / CP2112 not looked for: the hidapi package is not installed "
                         "(pip install 'magrig[bridges]')")
    if hid is not None:
        for kind, (vendor_id, product_id, model) in HID_BRIDGES.items():
            for info in hid.enumerate(vendor_id, product_id):
                found.append({"kind": kind, "model": model, "usb_id": f"{vendor_id:04x}:{product_id:04x}",
                              "serial_number": info.get("serial_number") or None})
    try:
        from drivers.transports.ft232h import list_devices

        for dev in list_devices(usb_backend):
            found.append({"kind": "ft232h", "model": "FT232H", "usb_id": f"{dev['vendor_id']:04x}:"
                          f"{dev['product_id']:04x}", "serial_number": dev["serial_number"]})
    except ImportError:
        notes.append("FT232H not looked for: the pyftdi package is not installed "
                     "(pip install 'magrig[bridges]')")
    except Exception as exc:  # noqa: BLE001 - pyusb without a libusb backend, or no USB access at all
        notes.append(f"FT232H not looked for: {exc}")
    return found, notes
