"""I2C transport: register reads and writes on an injected smbus2-like bus, with retries and a raw log.

    bus = open_smbus(1)                       # real hardware (or drivers.sim.transports.i2c_bus.FakeSMBus())
    link = I2CTransport(bus, 0x30, name="dut1", clock=clock, tries=3)
    link.read_byte(0x08, "status")            # -> int
    link.read_block(0x00, 7, "field data")    # -> bytes, one burst of at most 32 bytes
    link.write_byte(0x09, 0x01, "control 0")
    link.write_block(0x01, b"\\x02\\x20", "configuration")

Bursts use `read_i2c_block_data` / `write_i2c_block_data` (register pointer, repeated start, up to 32
bytes), which every chip here auto-increments through. Every transfer is retried (bounded, with
backoff on the injected clock); a NACK (OSError errno 121) ends as DeviceNotFound naming the device,
the operation and the address. Raw transfers are logged at DEBUG on "magrig.transport.i2c".
"""

from __future__ import annotations

import errno
import logging
from collections.abc import Callable, Generator
from typing import Any, Protocol, TypeVar

from drivers.clock import Clock, RealClock
from drivers.errors import DeviceError, DeviceNotFound, DeviceTimeout
from drivers.steps import run_steps
from drivers.transports.retry import with_retries

log = logging.getLogger("magrig.transport.i2c")

BLOCK_MAX_BYTES = 32  # SMBus I2C block transfer limit (smbus2 I2C_SMBUS_BLOCK_MAX)
NACK_ERRNO = errno.EREMOTEIO  # 121: "Remote I/O error", what Linux reports when no chip ACKs
NACK_ERRNOS = (NACK_ERRNO, errno.ENXIO)  # ENXIO (6): the same from some adapters (an MCP2221 bridge)
CLOCK_RESOLUTION_S = 1e-6  # epoch seconds as float resolve ~0.2 us: finer waits cannot advance
T = TypeVar("T")


class SMBusLike(Protocol):
    """The subset of smbus2.SMBus the drivers use."""

    def read_byte_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int: ...

    def write_byte_data(
        self, i2c_addr: int, register: int, value: int, force: bool | None = None
    ) -> None: ...

    def read_i2c_block_data(
        self, i2c_addr: int, register: int, length: int, force: bool | None = None
    ) -> list[int]: ...

    def write_i2c_block_data(
        self, i2c_addr: int, register: int, data: list[int], force: bool | None = None
    ) -> None: ...


def open_smbus(bus_number: int) -> Any:
    """Open /dev/i2c-<bus_number> with smbus2; a missing or forbidden bus is a clear DeviceNotFound."""
    from smbus2 import SMBus  # imported here so simulations never need the bus device

    path = f"/dev/i2c-{bus_number}"
    try:
        return SMBus(bus_number)
    except FileNotFoundError as exc:
        raise DeviceNotFound(f"i2c-{bus_number}", "open bus", f"{path} does not exist") from exc
    except PermissionError as exc:
        raise DeviceNotFound(
            f"i2c-{bus_number}", "open bus", f"no permission to open {path} (add the user to group i2c)"
        ) from exc


def _hex(data: bytes) -> str:
    return data.hex(" ") or "-"


class I2CTransport:
    """One chip at one address on a shared bus. The transport never closes the bus: others share it."""

    def __init__(
        self,
        bus: SMBusLike,
        address: int,
        *,
        name: str,
        clock: Clock | None = None,
        tries: int = 3,
        backoff_s: float = 0.002,
    ):
        self.bus = bus
        self.address = address
        self.name = name
        self.clock = clock or RealClock()
        self.tries = tries
        self.backoff_s = backoff_s

    # --- transfers --------------------------------------------------------------------------------
    def read_byte(self, register: int, what: str) -> int:
        return self.read_block(register, 1, what)[0]

    # The transfers are the hot path of a many-DUT campaign: the first try goes straight to the bus, and
    # the operation's name, the retries and the raw log's text are made only when they are needed.
    def read_block(self, register: int, length: int, what: str) -> bytes:
        if not 1 <= length <= BLOCK_MAX_BYTES:
            raise ValueError(f"I2C burst of {length} bytes: must be 1..{BLOCK_MAX_BYTES}")

        def transfer() -> bytes:
            if length == 1:
                return bytes([self.bus.read_byte_data(self.address, register)])
            return bytes(self.bus.read_i2c_block_data(self.address, register, length))

        try:
            data = transfer()
        except (OSError, DeviceError) as exc:
            data = self._retried(transfer, f"read {what} register 0x{register:02X}", exc)
        if len(data) != length:
            raise DeviceError(self.name, f"read {what} register 0x{register:02X}",
                              f"got {len(data)} bytes, expected {length}")
        if log.isEnabledFor(logging.DEBUG):
            log.debug("%s: 0x%02X read 0x%02X -> %s", self.name, self.address, register, _hex(data),
                      extra={"device": self.name})
        return data

    def write_byte(self, register: int, value: int, what: str) -> None:
        self.write_block(register, bytes([value]), what)

    def write_block(self, register: int, data: bytes, what: str) -> None:
        if not 1 <= len(data) <= BLOCK_MAX_BYTES:
            raise ValueError(f"I2C burst of {len(data)} bytes: must be 1..{BLOCK_MAX_BYTES}")
        if log.isEnabledFor(logging.DEBUG):
            log.debug("%s: 0x%02X write 0x%02X <- %s", self.name, self.address, register, _hex(data),
                      extra={"device": self.name})

        def transfer() -> None:
            if len(data) == 1:
                self.bus.write_byte_data(self.address, register, data[0])
            else:
                self.bus.write_i2c_block_data(self.address, register, list(data))

        try:
            transfer()
        except (OSError, DeviceError) as exc:
            self._retried(transfer, f"write {what} register 0x{register:02X}", exc)

    def _retried(self, transfer: Callable[[], T], operation: str, failed: BaseException) -> T:
        """The tries after a first that raised `failed` (an OSError of the bus, or the DeviceError of an
        I2C switch on the way), with backoff; the last failure raised naming whose fault it is."""
        if isinstance(failed, OSError):
            error = self._as_device_error(failed, operation)
            error.__cause__ = failed
            failed = error

        def attempt() -> T:
            try:
                return transfer()
            except OSError as exc:
                raise self._as_device_error(exc, operation) from exc

        try:
            return with_retries(
                attempt, device=self.name, operation=operation, tries=self.tries,
                backoff_s=self.backoff_s, clock=self.clock, failed=failed,
            )
        except DeviceError as exc:
            cause = exc.__cause__
            if isinstance(cause, DeviceError) and cause.device != self.name:
                # Another device failed on the way (an I2C switch in front of this chip): its fault,
                # named as its own, not as this chip's.
                raise type(cause)(
                    cause.device, cause.operation,
                    f"{cause.detail} (after {self.tries} tries, on the way to {self.name} {operation})",
                ) from cause
            raise

    def _as_device_error(self, exc: OSError, operation: str) -> DeviceError:
        if exc.errno in NACK_ERRNOS:
            return DeviceNotFound(self.name, operation, f"no ACK at 0x{self.address:02X}")
        if exc.errno == errno.ETIMEDOUT:
            # a CP2112 bridge reports a chip that does not ACK this way too
            return DeviceTimeout(self.name, operation, f"bus timeout (or no ACK) at 0x{self.address:02X}")
        return DeviceError(self.name, operation, f"I2C error at 0x{self.address:02X}: {exc}")

    # --- waiting ----------------------------------------------------------------------------------
    def wait_until(
        self,
        ready: Callable[[], bool],
        *,
        what: str,
        first_wait_s: float,
        timeout_s: float,
        poll_s: float = 0.001,
    ) -> None:
        """Sleep the expected conversion time, then poll `ready` every `poll_s` until `timeout_s`
        (counted from the call) has passed; DeviceTimeout names what was awaited."""
        run_steps(self.wait_steps(ready, what=what, first_wait_s=first_wait_s, timeout_s=timeout_s,
                                  poll_s=poll_s), self.clock)

    def wait_steps(
        self,
        ready: Callable[[], bool],
        *,
        what: str,
        first_wait_s: float,
        timeout_s: float,
        poll_s: float = 0.001,
    ) -> Generator[float, None, None]:
        """wait_until as steps (drivers/steps.py): yields each wait instead of sleeping it."""
        start = self.clock.now()
        deadline = start + timeout_s
        yield first_wait_s
        while not ready():
            remaining_s = deadline - self.clock.now()
            if remaining_s < CLOCK_RESOLUTION_S:
                waited_ms = (self.clock.now() - start) * 1e3
                raise DeviceTimeout(self.name, f"wait for {what}", f"not ready after {waited_ms:.1f} ms")
            yield min(poll_s, remaining_s)
