"""Who shares a wire: I2C bus segments (a bus, or one channel of a switch on it) and serial lines.

    problems(station)   -> [(key path, message)]: address clashes on a segment, a device at a switch's
                           address, a mux or line on a device that does not talk I2C / serial, two device
                           ids or two baud rates on one serial line

A segment is (simulated?, bus, switch address, channel), or (simulated?, bus, None, None) for the devices
wired to the bus itself. A simulated chip follows the rules of a real one: with an explicit `address` it
sits on simulated bus `bus` (rig/devices/simulated/bench.py), where two chips at one address without a switch
clash as they would on `kind: i2c`; only a simulated chip with neither `address` nor `mux` gets a bus of its
own (nothing was said about its wiring). Real serial devices share a line when they name the same port;
simulated ones by `line:`.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

from rig.core.configbase import BRIDGE_KINDS
from rig.core.ports import port_key

Problem = tuple[tuple[str | int, ...], str]


def _where(path: tuple) -> str:
    return f"{path[0]}[{path[1]}]"


def _segment_text(bus: int | str, mux) -> str:
    where = f"i2c-{bus}" if isinstance(bus, int) else bus  # a bridge's bus goes by its own label
    return where if mux is None else f"{where} switch 0x{mux.address:02X} channel {mux.channel}"


def i2c_problems(devices: list[tuple[tuple, Any]]) -> Iterator[Problem]:
    taken: dict[tuple, tuple[str, tuple]] = {}  # (sim, bus, mux addr, channel, address) -> (name, path)
    switches: dict[tuple, set[int]] = {}  # (sim, bus) -> switch addresses
    placed = []
    for path, dev in devices:
        t = dev.transport
        mux = getattr(t, "mux", None)
        if t.kind not in ("i2c", "sim", *BRIDGE_KINDS):
            continue
        if (mux is not None or getattr(t, "address", None) is not None) and "i2c" not in dev.spec.transports:
            yield (*path, "transport"), f"{dev.device_type} is not an I2C device: no address or mux"
            continue
        sim = dev.simulated
        if t.kind == "sim" and mux is None and t.address is None:
            continue  # no wiring stated: the simulated chip gets a bus of its own
        segment = (sim, t.bus, None if mux is None else mux.address, None if mux is None else mux.channel)
        if mux is not None:
            switches.setdefault((sim, t.bus), set()).add(mux.address)
        key = (*segment, t.address)
        if key in taken:
            other, other_path = taken[key]
            yield (*path, "transport", "address"), (
                f"0x{t.address:02X} on {_segment_text(t.bus, mux)} is taken twice: {dev.name} and "
                f"{other} ({_where(other_path)}); put one behind another switch channel")
            continue
        taken[key] = (dev.name, path)
        placed.append((path, dev, sim))
    for path, dev, sim in placed:
        t = dev.transport
        if t.address in switches.get((sim, t.bus), set()):
            yield (*path, "transport", "address"), (
                f"0x{t.address:02X} on {_segment_text(t.bus, None)} is the address of an I2C switch there: "
                f"{dev.name} would answer together with the switch")


def serial_problems(devices: list[tuple[tuple, Any]]) -> Iterator[Problem]:
    lines: dict[tuple, list[tuple[tuple, Any]]] = {}
    for path, dev in devices:
        t = dev.transport
        if t.kind == "sim" and getattr(t, "line", None) is not None:
            if "serial" not in dev.spec.transports:
                yield (*path, "transport", "line"), f"{dev.device_type} is not a serial device: no line"
                continue
            lines.setdefault(("sim", t.line), []).append((path, dev))
        elif t.kind == "serial":
            lines.setdefault(("serial", port_key(t.port)), []).append((path, dev))
    for (_, line), members in lines.items():
        ids: dict[int, tuple[str, tuple]] = {}
        bauds: dict[int, tuple[str, tuple]] = {}
        for path, dev in members:
            device_id = getattr(dev.device_options, "device_id", 0)
            if device_id in ids:
                other, other_path = ids[device_id]
                yield (*path, "options", "device_id"), (
                    f"device id {device_id} on line {line} is taken twice: {dev.name} and {other} "
                    f"({_where(other_path)})")
            ids.setdefault(device_id, (dev.name, path))
            baud = getattr(dev.transport, "baudrate", None)
            if baud is not None:
                bauds.setdefault(baud, (dev.name, path))
        if len(bauds) > 1:
            (b1, (n1, _)), (b2, (n2, p2)) = list(bauds.items())[:2]
            yield (*p2, "transport", "baudrate"), (
                f"line {line} runs at one baud rate: {n2} says {b2}, {n1} says {b1}")


def problems(station) -> list[Problem]:
    devices = list(station._named_devices())
    return [*i2c_problems(devices), *serial_problems(devices)]
