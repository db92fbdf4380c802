"""Bounded retries with backoff, shared by every transport."""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import TypeVar

from drivers.clock import Clock, RealClock
from drivers.errors import DeviceError, DeviceTimeout

T = TypeVar("T")
log = logging.getLogger("magrig.transport")


def with_retries(
    op: Callable[[], T],
    *,
    device: str,
    operation: str,
    tries: int = 3,
    backoff_s: float = 0.02,
    clock: Clock | None = None,
    retry_on: tuple[type[BaseException], ...] = (DeviceError, OSError, TimeoutError),
    recover: Callable[[], None] | None = None,
    failed: BaseException | None = None,
) -> T:
    """Call `op` up to `tries` times. Between tries: log a warning (its record carries `device` and the
    exception as `fault`, so a session can code it), call `recover` (e.g. reconnect), back off (doubling).
    The last failure is raised as a DeviceError naming device and operation. `failed`: the caller made
    the first try itself (a fast path that builds nothing until something fails) and it raised this."""
    clock = clock or RealClock()
    delay = backoff_s
    last: BaseException | None = None
    for attempt in range(1, tries + 1):
        try:
            if failed is not None and attempt == 1:
                raise failed
            return op()
        except retry_on as exc:  # noqa: PERF203 - retry loop
            last = exc
            if attempt == tries:
                break
            log.warning(
                "%s: %s: try %d of %d failed: %s", device, operation, attempt, tries, exc,
                extra={"device": device, "operation": operation, "event": "retry", "fault": exc},
            )
            if recover is not None:
                try:
                    recover()
                except (DeviceError, OSError) as rexc:
                    log.warning("%s: reconnect failed: %s", device, rexc, extra={"device": device})
            clock.sleep(delay)
            delay *= 2
    if isinstance(last, DeviceError):
        detail = last.detail
        cls = type(last)
    else:
        detail = str(last) or type(last).__name__
        cls = DeviceTimeout if isinstance(last, TimeoutError) else DeviceError
    raise cls(device, operation, f"{detail} (after {tries} tries)") from last
