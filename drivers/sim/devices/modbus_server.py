"""A real pymodbus server in a background thread, for the Modbus device simulators.

    server = ModbusSimServer(devices, framing="tcp")   # or framing="rtu": RTU frames with CRC over TCP
    port = server.start()                               # 127.0.0.1, an ephemeral port
    ...
    server.stop()

`devices` is one pymodbus `SimDevice` or a list of them (several ids on one line, like an RS-485 bus).
Device logic lives in each SimDevice's `action` hook; this harness adds the fault hooks every simulator
shares: `silence(n)` (the next n replies are lost), `fail_next(n, code)` (the next n requests get a Modbus
exception reply), `unplug()` / `replug()` (the server goes away and comes back on the same port), and
`get_values` / `set_values` for tests that look at or poke the registers from outside the protocol path.
`faults` (a drivers.sim.devices.faults.DeviceFaults) draws a fault for every request: "no_reply" loses the
reply (the request takes effect), "unplug" loses it without effect, "exception" answers exception 6 (server
device busy: a transient refusal), "garbled" corrupts one byte of the reply frame (with RTU framing its
CRC no longer matches; with TCP framing it is the MBAP length, so the client waits for bytes that never come).

With framing="rtu" the server listens on `socket://127.0.0.1:0`: pymodbus serves the RTU framer over a
TCP socket, and a client opens it through pyserial's `socket://` URL handler, so frames carry the
real RTU address byte and CRC without needing a pty.
"""

from __future__ import annotations

import asyncio
import socket
import threading
from collections.abc import Callable, Sequence

from pymodbus import FramerType
from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

HOST = "127.0.0.1"
START_TIMEOUT_S = 5.0


def register_block(address: int, values: Sequence[int], *, readonly: bool = False) -> SimData:
    """Consecutive 16-bit registers starting at `address`, holding `values`."""
    return SimData(address, values=[int(v) for v in values], datatype=DataType.REGISTERS, readonly=readonly)


def value_after_write(
    registers: list[int], start_address: int, address: int, set_values
) -> Callable[[int], int]:
    """reg -> the value a write will leave there. Action hooks run before the write is applied; this
    lets them see a multi-register value whole even when the write covers only part of it."""

    def value(reg: int) -> int:
        if address <= reg < address + len(set_values):
            return int(set_values[reg - address])
        return registers[reg - start_address]

    return value


class ModbusSimServer:
    """A threaded pymodbus server with fault hooks; start() -> port, stop()."""

    def __init__(self, devices: SimDevice | Sequence[SimDevice], *, framing: str = "tcp", faults=None):
        if framing not in ("tcp", "rtu"):
            raise ValueError(f"framing must be 'tcp' or 'rtu', not {framing!r}")
        self.framing = framing
        device_list = [devices] if isinstance(devices, SimDevice) else list(devices)
        self._devices = [self._with_fault_hook(d) for d in device_list]
        self.port = 0
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server = None
        self._stop_evt: asyncio.Event | None = None
        self._lock = threading.Lock()
        self._silent_replies = 0
        self._exceptions: list[ExcCodes] = []
        self._garbled_replies = 0
        self.faults = faults
        self.requests_seen = 0

    # --- fault hooks ------------------------------------------------------------------------------
    def silence(self, n_replies: int) -> None:
        """Lose the next n replies (the request still takes effect, as when a reply is lost on the line)."""
        with self._lock:
            self._silent_replies = n_replies

    def fail_next(self, n_requests: int, code: ExcCodes | int = ExcCodes.DEVICE_FAILURE) -> None:
        """Answer the next n requests with a Modbus exception reply carrying `code`."""
        with self._lock:
            self._exceptions = [ExcCodes(code)] * n_requests

    def unplug(self) -> None:
        """The device disappears: listener and open connections close; connects are refused."""
        self._stop_thread()

    def replug(self) -> int:
        """The device comes back on the same port."""
        return self._start_thread(self.port)

    # --- life cycle -------------------------------------------------------------------------------
    def start(self) -> int:
        return self._start_thread(0)

    def stop(self) -> None:
        self._stop_thread()

    def __enter__(self) -> ModbusSimServer:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    # --- register access from outside the protocol path (runs the device's action too) ------------
    def get_values(self, device_id: int, address: int, count: int) -> list[int]:
        return self._call(self._server.async_getValues(device_id, 3, address, count))

    def set_values(self, device_id: int, address: int, values: list[int]) -> None:
        self._call(self._server.async_setValues(device_id, 16, address, values))

    # --- internals --------------------------------------------------------------------------------
    def _call(self, coro):
        if self._loop is None:
            coro.close()
            raise RuntimeError("simulator is not running")
        return asyncio.run_coroutine_threadsafe(coro, self._loop).result(START_TIMEOUT_S)

    def _with_fault_hook(self, device: SimDevice) -> SimDevice:
        inner = device.action

        async def action(function_code, start_address, address, count, registers, set_values):
            with self._lock:
                self.requests_seen += 1
                if self._exceptions:
                    return self._exceptions.pop()
                injected = self._injected_fault()
            if injected is not None:
                return injected
            if inner is None:
                return None
            return await inner(function_code, start_address, address, count, registers, set_values)

        device.action = action
        return device

    def _injected_fault(self) -> ExcCodes | None:
        """Draw this request's fault (lock held); an exception code to answer, else None (go on)."""
        kind = self.faults.draw() if self.faults is not None else None
        if kind == "unplug":  # nobody there: no effect, no reply
            self._silent_replies += 1
            return ExcCodes.DEVICE_FAILURE
        if kind == "no_reply":
            self._silent_replies += 1
        elif kind == "garbled":
            self._garbled_replies += 1
        elif kind == "exception":
            return ExcCodes.DEVICE_BUSY
        return None

    def _trace_packet(self, sending: bool, data: bytes) -> bytes:
        if sending:
            with self._lock:
                if self._silent_replies > 0:
                    self._silent_replies -= 1
                    return b""
                if self._garbled_replies > 0 and data:
                    self._garbled_replies -= 1
                    return self._garbled(data)
        return data

    def _garbled(self, frame: bytes) -> bytes:
        out = bytearray(frame)
        if self.framing == "rtu":
            out[len(out) // 2] ^= 0x5A  # any flipped byte breaks the CRC
        else:  # TCP carries no checksum of its own: a too-long MBAP length is what the client can notice
            out[5] = min(0xFF, out[5] + 4)
        return bytes(out)

    def _make_server(self, port: int):
        if self.framing == "tcp":
            return ModbusTcpServer(self._devices, address=(HOST, port), trace_packet=self._trace_packet)
        return ModbusSerialServer(
            self._devices,
            framer=FramerType.RTU,
            port=f"socket://{HOST}:{port}",
            trace_packet=self._trace_packet,
        )

    def _start_thread(self, port: int) -> int:
        if self._thread is not None:
            return self.port
        ready = threading.Event()
        failure: list[BaseException] = []

        async def main():
            try:
                self._server = self._make_server(port)
                await self._server.serve_forever(background=True)
                self.port = self._server.transport.sockets[0].getsockname()[1]
                self._loop = asyncio.get_running_loop()
                self._stop_evt = asyncio.Event()
            except BaseException as exc:  # reported to the starting thread
                failure.append(exc)
                ready.set()
                return
            ready.set()
            await self._stop_evt.wait()
            await self._server.shutdown()

        self._thread = threading.Thread(target=asyncio.run, args=(main(),), daemon=True, name="modbus-sim")
        self._thread.start()
        if not ready.wait(START_TIMEOUT_S) or failure:
            self._thread = None
            raise RuntimeError(f"Modbus simulator did not start: {failure[0] if failure else 'timeout'}")
        return self.port

    def _stop_thread(self) -> None:
        if self._thread is None:
            return
        self._loop.call_soon_threadsafe(self._stop_evt.set)
        self._thread.join(START_TIMEOUT_S)
        self._thread = None
        self._loop = None


class SimulatedModbusDevice:
    """Base of the device simulators: one SimDevice on its own server, with the server's fault hooks.

    Subclasses define `sim_device()` (registers and the action hook that drives the world).
    To put several simulated devices on one line, build `ModbusSimServer([a.sim_device(), b.sim_device()])`.
    """

    def __init__(self, unit: int = 1, framing: str = "tcp"):
        self.unit = unit
        self.framing = framing
        self.server: ModbusSimServer | None = None
        self.faults = None  # a drivers.sim.devices.faults.DeviceFaults, set before start()

    def sim_device(self) -> SimDevice:
        raise NotImplementedError

    def start(self) -> int:
        """Serve on 127.0.0.1; returns the TCP port."""
        if self.server is None:
            self.server = ModbusSimServer(self.sim_device(), framing=self.framing, faults=self.faults)
        return self.server.start()

    def stop(self) -> None:
        if self.server is not None:
            self.server.stop()

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def port(self) -> int:
        return self.server.port if self.server else 0

    def register_values(self, address: int, count: int = 1) -> list[int]:
        """Registers as a client would read them now (the device logic refreshes them first)."""
        return self.server.get_values(self.unit, address, count)

    # fault hooks, delegated to the server
    def silence(self, n_replies: int) -> None:
        self.server.silence(n_replies)

    def fail_next(self, n_requests: int, code: ExcCodes | int = ExcCodes.DEVICE_FAILURE) -> None:
        self.server.fail_next(n_requests, code)

    def unplug(self) -> None:
        self.server.unplug()

    def replug(self) -> int:
        return self.server.replug()


class ScriptedPeer:
    """A raw TCP peer that plays a fixed transcript, for byte-exact driver tests.

    `script` is a list of (request_bytes, reply_bytes | None): for each step the peer reads as many bytes
    as the expected request has, records what actually came, and sends the reply (None: stays silent).
    A client reaches it over Modbus TCP at `port`, or with RTU framing at socket://127.0.0.1:`port`.
    Compare `received` with the expected requests after the exchange.
    """

    def __init__(self, script: Sequence[tuple[bytes, bytes | None]], *, read_timeout_s: float = 2.0):
        self.script = list(script)
        self.received: list[bytes] = []
        self.connections = 0
        self._listener = socket.create_server((HOST, 0))
        self._listener.settimeout(read_timeout_s)
        self.port = self._listener.getsockname()[1]
        self._read_timeout_s = read_timeout_s
        self._thread = threading.Thread(target=self._run, daemon=True, name="modbus-scripted-peer")
        self._thread.start()

    def _run(self) -> None:
        conn = None
        try:
            for expected, reply in self.script:
                if conn is None:
                    conn, _ = self._listener.accept()
                    conn.settimeout(self._read_timeout_s)
                    self.connections += 1
                got = b""
                while len(got) < len(expected):
                    chunk = conn.recv(len(expected) - len(got))
                    if not chunk:  # the client hung up (e.g. reconnect after a timeout): take the next one
                        conn.close()
                        conn, _ = self._listener.accept()
                        conn.settimeout(self._read_timeout_s)
                        self.connections += 1
                        continue
                    got += chunk
                self.received.append(got)
                if reply is not None:
                    conn.sendall(reply)
            while conn is not None and conn.recv(1):  # stay connected until the client hangs up
                pass
        except OSError:
            pass  # a timeout ends the script; the test compares `received`
        finally:
            if conn is not None:
                conn.close()

    def close(self) -> None:
        self._thread.join(self._read_timeout_s + 1.0)
        self._listener.close()

    def __enter__(self) -> ScriptedPeer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
