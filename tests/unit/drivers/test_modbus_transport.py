"""ModbusTransport: byte-exact frames (TCP MBAP and RTU with CRC), encodings, retries, errors, reconnect."""

from __future__ import annotations

import logging
import socket

import pytest
from pymodbus.simulator import SimDevice

from drivers.clock import SimClock
from drivers.errors import DeviceNotFound, DeviceTimeout, ProtocolError
from drivers.sim.devices.modbus_server import ModbusSimServer, ScriptedPeer, register_block
from drivers.transports.modbus import (
    ModbusTransport,
    decode_float32,
    decode_int16,
    decode_int32,
    decode_string,
    encode_float32,
    encode_int16,
    encode_int32,
    encode_string,
)

TIMEOUT_S = 0.2


def tcp(port: int, **kw) -> ModbusTransport:
    return ModbusTransport(
        name="chamber", host="127.0.0.1", port=port, timeout_s=TIMEOUT_S, clock=SimClock(), **kw
    )


def rtu(port: int, **kw) -> ModbusTransport:
    return ModbusTransport(
        name="chamber",
        serial_port=f"socket://127.0.0.1:{port}",
        baudrate=115200,
        timeout_s=TIMEOUT_S,
        clock=SimClock(),
        **kw,
    )


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# --- encodings ------------------------------------------------------------------------------------
def test_float32_word_orders():
    # 85.0 = 0x42AA0000: Watlow's default puts the low word first
    assert encode_float32(85.0, "little") == [0x0000, 0x42AA]
    assert encode_float32(85.0, "big") == [0x42AA, 0x0000]
    assert decode_float32([0x0000, 0x41BC], "little") == 23.5
    assert decode_float32([0xC1A0, 0x0000], "big") == -20.0


def test_int16_int32_and_string():
    assert encode_int16(-2) == 0xFFFE and decode_int16(0xFFFE) == -2
    assert encode_int32(-1500) == [0xFFFF, 0xFA24] and decode_int32([0xFFFF, 0xFA24]) == -1500
    assert encode_int32(70000, "little") == [0x1170, 0x0001]
    assert encode_string("AB-C", 3) == [0x4142, 0x2D43, 0x0000]
    assert decode_string([0x4142, 0x2D43, 0x0000]) == "AB-C"
    with pytest.raises(ValueError):
        encode_int16(40000)


# --- transcripts ----------------------------------------------------------------------------------
def test_tcp_read_and_write_frames():
    script = [
        # FC03 read 2 registers at 27586 (0x6BC2), unit 1, transaction 1
        (bytes.fromhex("0001 0000 0006 01 03 6bc2 0002"), bytes.fromhex("0001 0000 0007 01 03 04 0000 41bc")),
        # FC16 write [0x0000, 0x42AA] at 2782 (0x0ADE)
        (
            bytes.fromhex("0002 0000 000b 01 10 0ade 0002 04 0000 42aa"),
            bytes.fromhex("0002 0000 0006 01 10 0ade 0002"),
        ),
        # FC06 write 85 at 2794 (0x0AEA)
        (bytes.fromhex("0003 0000 0006 01 06 0aea 0055"), bytes.fromhex("0003 0000 0006 01 06 0aea 0055")),
    ]
    with ScriptedPeer(script) as peer:
        link = tcp(peer.port)
        assert link.read_float32(27586, word_order="little") == 23.5
        link.write_float32(2782, 85.0, word_order="little")
        link.write_register(2794, 85)
        link.close()
    assert peer.received == [request for request, _ in script]


def test_rtu_frames_carry_address_and_crc():
    script = [
        # unit 1, FC03, 2 registers at 100, CRC 85 D4 (low byte first)
        (bytes.fromhex("01 03 0064 0002 85d4"), bytes.fromhex("01 03 04 00e9 0000 2bc7")),
        # FC06 write 0x0352 (850) at 300
        (bytes.fromhex("01 06 012c 0352 c8f2"), bytes.fromhex("01 06 012c 0352 c8f2")),
    ]
    with ScriptedPeer(script) as peer:
        link = rtu(peer.port)
        assert link.read_holding(100, 2) == [233, 0]
        link.write_int16(300, 850)
        link.close()
    assert peer.received == [request for request, _ in script]


def test_exception_reply_is_a_protocol_error_and_not_retried():
    script = [(bytes.fromhex("0001 0000 0006 01 03 6bc2 0002"), bytes.fromhex("0001 0000 0003 01 83 02"))]
    with ScriptedPeer(script, read_timeout_s=0.5) as peer:
        link = tcp(peer.port)
        with pytest.raises(ProtocolError) as err:
            link.read_holding(27586, 2, operation="read chamber temperature")
        link.close()
    assert str(err.value) == "chamber: read chamber temperature: exception reply 2 (illegal data address)"
    assert len(peer.received) == 1


def test_busy_reply_is_retried():
    request = bytes.fromhex("0001 0000 0006 01 03 0064 0001")
    script = [
        (request, bytes.fromhex("0001 0000 0003 01 83 06")),
        (bytes.fromhex("0002 0000 0006 01 03 0064 0001"), bytes.fromhex("0002 0000 0005 01 03 02 00fa")),
    ]
    with ScriptedPeer(script) as peer:
        link = tcp(peer.port)
        assert link.read_int16(100) == 250
        link.close()
    assert len(peer.received) == 2


def test_silence_gives_device_timeout_after_tries_with_reconnects(caplog):
    request = bytes.fromhex("0001 0000 000b 01 10 0ade 0002 04 0000 42aa")
    script = [(request, None), (request[:1] + b"\x02" + request[2:], None), (b"\x00\x03" + request[2:], None)]
    with ScriptedPeer(script, read_timeout_s=2.0) as peer, caplog.at_level(logging.WARNING, "magrig"):
        link = tcp(peer.port, tries=3)
        with pytest.raises(DeviceTimeout) as err:
            link.write_float32(2782, 85.0, word_order="little", operation="write setpoint 85.0 degC")
        link.close()
    assert str(err.value) == "chamber: write setpoint 85.0 degC: no reply within 0.2 s (after 3 tries)"
    assert len(peer.received) == 3
    assert peer.connections == 3  # a fresh connection for each try: no stale reply can be mistaken
    retries = [r for r in caplog.records if "try" in r.getMessage()]
    assert len(retries) == 2 and all(r.device == "chamber" for r in retries)


def test_connection_refused_is_device_not_found():
    link = tcp(free_port())
    with pytest.raises(DeviceNotFound, match=r"chamber: connect: connection refused at 127\.0\.0\.1:\d+"):
        link.connect()
    with pytest.raises(DeviceNotFound, match=r"read holding registers 0\.\.0: connection refused .*3 tries"):
        link.read_holding(0, 1)


def test_frames_are_logged_at_debug(caplog):
    script = [
        (bytes.fromhex("0001 0000 0006 01 03 0064 0001"), bytes.fromhex("0001 0000 0005 01 03 02 00fa"))
    ]
    with ScriptedPeer(script) as peer, caplog.at_level(logging.DEBUG, "magrig.transport.modbus"):
        link = tcp(peer.port)
        link.read_holding(100, 1)
        link.close()
    lines = [r.getMessage() for r in caplog.records if r.name == "magrig.transport.modbus"]
    assert lines == [
        "chamber tx 00 01 00 00 00 06 01 03 00 64 00 01",
        "chamber rx 00 01 00 00 00 05 01 03 02 00 fa",
    ]


def test_refuses_values_that_are_not_words():
    link = tcp(free_port())
    with pytest.raises(ValueError):
        link.write_register(1, 70000)
    with pytest.raises(ValueError):
        link.write_float32(1, float("nan"))


# --- against a real pymodbus server ---------------------------------------------------------------
@pytest.fixture
def server():
    srv = ModbusSimServer(SimDevice(id=1, simdata=[register_block(10, [1, 2, 3])]))
    srv.start()
    yield srv
    srv.stop()


def test_unplug_then_replug_recovers(server):
    link = tcp(server.port)
    assert link.read_holding(10, 3) == [1, 2, 3]
    server.unplug()
    with pytest.raises(DeviceNotFound, match="connection refused"):
        link.read_holding(10, 3, operation="read block")
    server.replug()
    assert link.read_holding(10, 3) == [1, 2, 3]
    link.close()


def test_injected_exception_and_lost_reply(server):
    link = tcp(server.port)
    server.fail_next(1, 4)
    with pytest.raises(ProtocolError, match="exception reply 4 \\(server device failure\\)"):
        link.read_holding(10, 1)
    server.silence(1)  # one lost reply: the retry gets through
    assert link.read_holding(11, 2) == [2, 3]
    with pytest.raises(ProtocolError, match="illegal data address"):
        link.read_holding(13, 1)
    link.close()


def test_rtu_against_server():
    srv = ModbusSimServer(SimDevice(id=3, simdata=[register_block(0, [7, 8])]), framing="rtu")
    port = srv.start()
    try:
        link = rtu(port, unit=3)
        assert link.read_holding(0, 2) == [7, 8]
        link.write_registers(0, [9, 10])
        assert srv.get_values(3, 0, 2) == [9, 10]
        link.close()
    finally:
        srv.stop()


def test_missing_serial_port_is_device_not_found():
    link = ModbusTransport(name="chamber", serial_port="/dev/does-not-exist", timeout_s=0.1, clock=SimClock())
    with pytest.raises(DeviceNotFound, match="chamber: connect: cannot open serial port /dev/does-not-exist"):
        link.connect()


def test_requires_exactly_one_link():
    with pytest.raises(ValueError, match="exactly one"):
        ModbusTransport(name="x", host="127.0.0.1", serial_port="/dev/null")
