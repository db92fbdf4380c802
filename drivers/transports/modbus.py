"""Modbus transport: a pymodbus sync client with our timeouts, retries, reconnects, frame log and errors.

Construct (the station YAML maps onto these keywords):

    ModbusTransport(name="chamber", host="10.0.0.5", port=502, unit=1, timeout_s=1.0, tries=3)  # TCP
    ModbusTransport(name="chamber", serial_port="/dev/ttyUSB0", baudrate=9600, parity="N",
                    stopbits=1, unit=1, timeout_s=1.0, tries=3)                                 # RTU
    (serial_port may be any pyserial URL, e.g. "socket://127.0.0.1:5020" for RTU frames over TCP)
    optional: backoff_s=0.05, clock=RealClock()

Every call has a timeout (timeout_s), up to `tries` attempts with doubling backoff on the injected clock,
and a reconnect between attempts (so a dropped link recovers, and a late reply to a timed-out request
cannot be taken for the next one's). pymodbus's own retries are set to 0 so these govern.
Raw frames are logged at DEBUG on "magrig.transport.modbus"; retries at WARNING on "magrig.transport".

Errors (rig.core.errors), each naming the device and the operation, e.g.
    DeviceTimeout  "chamber: write setpoint 85.0 degC: no reply within 1 s (after 3 tries)"
    ProtocolError  "coils: write setpoints: exception reply 3 (illegal data value)"   (not retried,
                   except 5 acknowledge / 6 busy)
    DeviceNotFound "turntable: connect: connection refused at 127.0.0.1:5020"

Register values are 16-bit words; typed helpers encode and decode int16, int32 and float32 with a
word order: "big" (high word first, the Modbus habit) or "little" (low word first, Watlow's default).
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable, Sequence
from typing import Literal, TypeVar

from pymodbus import FramerType
from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.client.mixin import ModbusClientMixin
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException

from drivers.clock import Clock, RealClock
from drivers.errors import DeviceError, DeviceNotFound, DeviceTimeout, ProtocolError
from drivers.transports.retry import with_retries

WordOrder = Literal["big", "little"]
T = TypeVar("T")

frame_log = logging.getLogger("magrig.transport.modbus")

EXCEPTION_MEANINGS = {
    1: "illegal function",
    2: "illegal data address",
    3: "illegal data value",
    4: "server device failure",
    5: "acknowledge",
    6: "server device busy",
    7: "negative acknowledge",
    8: "memory parity error",
    10: "gateway path unavailable",
    11: "gateway target device failed to respond",
}
RETRYABLE_EXCEPTION_CODES = {5, 6}  # the device says "later", not "never"

_DT = ModbusClientMixin.DATATYPE


# --- pure encoding helpers (also used by the simulators) -----------------------------------------
def encode_int16(value: int) -> int:
    if not -32768 <= value <= 32767:
        raise ValueError(f"{value} does not fit in int16")
    return value & 0xFFFF


def decode_int16(word: int) -> int:
    return word - 0x10000 if word & 0x8000 else word


def encode_int32(value: int, word_order: WordOrder = "big") -> list[int]:
    if not -(2**31) <= value < 2**31:
        raise ValueError(f"{value} does not fit in int32")
    return ModbusClientMixin.convert_to_registers(int(value), _DT.INT32, word_order=word_order)


def decode_int32(words: Sequence[int], word_order: WordOrder = "big") -> int:
    return int(ModbusClientMixin.convert_from_registers(list(words), _DT.INT32, word_order=word_order))


def encode_float32(value: float, word_order: WordOrder = "big") -> list[int]:
    return ModbusClientMixin.convert_to_registers(float(value), _DT.FLOAT32, word_order=word_order)


def decode_float32(words: Sequence[int], word_order: WordOrder = "big") -> float:
    return float(ModbusClientMixin.convert_from_registers(list(words), _DT.FLOAT32, word_order=word_order))


def encode_string(text: str, n_registers: int) -> list[int]:
    """ASCII, two characters per register, first character in the high byte, zero padded."""
    raw = text.encode("ascii")[: 2 * n_registers].ljust(2 * n_registers, b"\0")
    return [raw[i] << 8 | raw[i + 1] for i in range(0, len(raw), 2)]


def decode_string(words: Sequence[int]) -> str:
    raw = b"".join(int(w).to_bytes(2, "big") for w in words)
    return raw.split(b"\0", 1)[0].decode("ascii", errors="replace").strip()


def exception_text(code: int) -> str:
    return f"exception reply {code} ({EXCEPTION_MEANINGS.get(code, 'unknown code')})"


class ModbusTransport:
    """One Modbus device (one unit id) on a TCP or RTU link."""

    def __init__(
        self,
        *,
        name: str,
        host: str | None = None,
        port: int = 502,
        serial_port: str | None = None,
        baudrate: int = 9600,
        parity: str = "N",
        stopbits: int = 1,
        unit: int = 1,
        timeout_s: float = 1.0,
        tries: int = 3,
        backoff_s: float = 0.05,
        clock: Clock | None = None,
    ):
        if (host is None) == (serial_port is None):
            raise ValueError(f"{name}: give exactly one of host (Modbus TCP) or serial_port (Modbus RTU)")
        self.name = name
        self.unit = unit
        self.timeout_s = timeout_s
        self.tries = tries
        self.backoff_s = backoff_s
        self.clock = clock or RealClock()
        self._lock = threading.RLock()
        self._rx = b""
        if host is not None:
            self.link = f"tcp {host}:{port}"
            self.client = ModbusTcpClient(
                host, port=port, timeout=timeout_s, retries=0, trace_packet=self._trace_packet
            )
        else:
            self.link = f"rtu {serial_port} {baudrate} 8{parity}{stopbits}"
            self.client = ModbusSerialClient(
                serial_port,
                framer=FramerType.RTU,
                baudrate=baudrate,
                parity=parity,
                stopbits=stopbits,
                timeout=timeout_s,
                retries=0,
                trace_packet=self._trace_packet,
            )
        self._not_found = (
            f"connection refused at {host}:{port}"
            if host is not None
            else f"cannot open serial port {serial_port}"
        )
        self._where = f"{host}:{port}" if host is not None else str(serial_port)

    # --- link -------------------------------------------------------------------------------------
    def connect(self) -> None:
        with self._lock:
            self._ensure_connected("connect")

    def close(self) -> None:
        try:
            self.client.close()
        except Exception:  # noqa: BLE001 - close never raises
            pass

    def describe(self) -> dict:
        return {"link": self.link, "unit": self.unit, "timeout_s": self.timeout_s, "tries": self.tries}

    # --- raw register access ----------------------------------------------------------------------
    def read_holding(self, address: int, count: int, *, operation: str | None = None) -> list[int]:
        op = operation or f"read holding registers {address}..{address + count - 1}"
        rr = self._call(
            op, lambda: self.client.read_holding_registers(address, count=count, device_id=self.unit)
        )
        return self._checked_registers(rr, count, op)

    def read_input(self, address: int, count: int, *, operation: str | None = None) -> list[int]:
        op = operation or f"read input registers {address}..{address + count - 1}"
        rr = self._call(
            op, lambda: self.client.read_input_registers(address, count=count, device_id=self.unit)
        )
        return self._checked_registers(rr, count, op)

    def write_register(self, address: int, value: int, *, operation: str | None = None) -> None:
        if not 0 <= value <= 0xFFFF:
            raise ValueError(f"{self.name}: register value {value} is not a 16-bit word")
        op = operation or f"write register {address}"
        self._call(op, lambda: self.client.write_register(address, value, device_id=self.unit))

    def write_registers(self, address: int, values: Sequence[int], *, operation: str | None = None) -> None:
        words = [int(v) for v in values]
        if any(not 0 <= w <= 0xFFFF for w in words):
            raise ValueError(f"{self.name}: register values {words} are not all 16-bit words")
        op = operation or f"write registers {address}..{address + len(words) - 1}"
        self._call(op, lambda: self.client.write_registers(address, words, device_id=self.unit))

    # --- typed helpers ----------------------------------------------------------------------------
    def read_int16(self, address: int, *, operation: str | None = None) -> int:
        return decode_int16(self.read_holding(address, 1, operation=operation)[0])

    def write_int16(self, address: int, value: int, *, operation: str | None = None) -> None:
        self.write_register(address, encode_int16(value), operation=operation)

    def read_int32(self, address: int, *, word_order: WordOrder = "big", operation: str | None = None) -> int:
        return decode_int32(self.read_holding(address, 2, operation=operation), word_order)

    def write_int32(
        self, address: int, value: int, *, word_order: WordOrder = "big", operation: str | None = None
    ) -> None:
        self.write_registers(address, encode_int32(value, word_order), operation=operation)

    def read_float32(
        self, address: int, *, word_order: WordOrder = "big", operation: str | None = None
    ) -> float:
        return decode_float32(self.read_holding(address, 2, operation=operation), word_order)

    def write_float32(
        self, address: int, value: float, *, word_order: WordOrder = "big", operation: str | None = None
    ) -> None:
        if not math.isfinite(value):
            raise ValueError(f"{self.name}: refusing to write non-finite value {value}")
        self.write_registers(address, encode_float32(value, word_order), operation=operation)

    def read_string(self, address: int, n_registers: int, *, operation: str | None = None) -> str:
        return decode_string(self.read_holding(address, n_registers, operation=operation))

    # --- internals --------------------------------------------------------------------------------
    def _trace_packet(self, sending: bool, data: bytes) -> bytes:
        if sending:
            frame_log.debug("%s tx %s", self.name, data.hex(" "), extra={"device": self.name})
            self._rx = b""
        else:
            self._rx = data  # the receive buffer grows as bytes arrive; logged once the call ends
        return data

    def _log_rx(self) -> None:
        if self._rx:
            frame_log.debug("%s rx %s", self.name, self._rx.hex(" "), extra={"device": self.name})
            self._rx = b""

    def _ensure_connected(self, operation: str) -> None:
        if not self.client.connected and not self.client.connect():
            raise DeviceNotFound(self.name, operation, self._not_found)

    def _reconnect(self, operation: str) -> None:
        self.client.close()
        self._ensure_connected(operation)

    def _once(self, operation: str, request: Callable[[], T]) -> T:
        """One attempt, with pymodbus's exceptions turned into ours."""
        self._ensure_connected(operation)
        try:
            response = request()
        except ModbusIOException as exc:
            raise DeviceTimeout(self.name, operation, f"no reply within {self.timeout_s:g} s") from exc
        except ConnectionException as exc:
            raise DeviceError(self.name, operation, f"link to {self._where} dropped") from exc
        except ModbusException as exc:
            raise ProtocolError(self.name, operation, f"bad reply: {exc}") from exc
        finally:
            self._log_rx()
        code = getattr(response, "exception_code", None)
        if response.isError() and code in RETRYABLE_EXCEPTION_CODES:
            raise ProtocolError(self.name, operation, exception_text(code))
        return response

    def _call(self, operation: str, request: Callable[[], T]) -> T:
        with self._lock:
            response = with_retries(
                lambda: self._once(operation, request),
                device=self.name,
                operation=operation,
                tries=self.tries,
                backoff_s=self.backoff_s,
                clock=self.clock,
                recover=lambda: self._reconnect(operation),
            )
        if response.isError():
            code = getattr(response, "exception_code", None)
            raise ProtocolError(
                self.name, operation, exception_text(code) if code else f"error reply {response}"
            )
        return response

    def _checked_registers(self, response, count: int, operation: str) -> list[int]:
        registers = list(getattr(response, "registers", []))
        if len(registers) != count:
            raise ProtocolError(self.name, operation, f"asked for {count} registers, got {len(registers)}")
        return registers
