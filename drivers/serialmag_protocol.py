"""The Honeywell HMR2300 serial magnetometer's wire protocol: its commands, replies and sample line, as
data and small pure functions (the device: drivers/serialmag.py).

Commands and replies, from the datasheet command table (hardware-notes 2.3); `dd` = two-digit id, CR ends
each::

    *ddA        ASCII output            -> "ASCII_ON"   (sent at connect; it also finds the baud rate)
    *ddWE       write enable            -> "OK"         (sent just before each setting command below)
    *ddR=nnn    rate in Hz              -> "OK"
    *ddTN/TF    auto S/R on/off         -> "S/R_ON" / "S/R_OFF"
    *dd]S/]R    one SET / RESET pulse   -> "SET" / "RST"
    *99WE, *99!BR=F / *99!BR=S   every device on the line to 19200 / 9600 baud; no reply is awaited
    *ddP        poll one sample         -> one sample line
    *ddC        continuous stream       -> sample lines at the set rate until Esc (0x1B)
    *dd#, *ddF, *ddQ   serial number, firmware, setup -> one text line each (format not in the notes)
    anything the device does not accept -> "Re-enter": a ProtocolError naming the command

BAUD. The notes give: 9600 or 19200 baud 8N1, switched with `*99!BR=S|F`, and "19200 baud is needed for
40 and 50 Hz". They do not give the power-on rate, nor what 60, 100, 123 and 154 Hz need. Arithmetic on
the 28-byte ASCII sample (280 bits at 8N1): 9600 baud carries at most 34 samples/s and 19200 at most 68,
so 60 Hz needs 19200 too, and 100 Hz and above cannot be streamed in ASCII at all (presumably the binary
format is meant for them; its 7-byte layout is not verified in the notes, so this driver does not use
it). The driver switches the line to 19200 when the rate needs it and never back down (another device on
the line may need it). After a reopen it finds the device's rate again: `*ddA` at the line's rate, then
at the other one.

Shared RS-485 line: each device answers only its own id; the line's lock keeps one device's exchanges
(and a whole SET/RESET read or stream) together. The HMR2300 has no temperature output: temp_c is None
(the rig places a temperature probe next to the DUT).

Sample line, 28 bytes: three 7-byte fields, each followed by two spaces, then CR::

    column  0-6    7-8   9-15   16-17  18-24  25-26  27
            X      "  "  Y      "  "   Z      "  "   CR

A field is a sign byte (space or "-") then the magnitude right-aligned in 6 bytes, thousands separated
by a comma: " 12,345", "- 1,234", "    567", "      0". 15000 counts = 1 gauss = 100000 nT; the range
is +-2 gauss (+-30,000 counts, a reading at the rail is flagged "saturated").

Line noise: a reply longer than 28 bytes whose last 28 bytes are a valid sample is accepted (the noise
before it is logged); any other malformed line is logged and discarded, and the poll is repeated within
the transport's bounded retries. Streams tolerate as many bad lines in a row as the transport's tries.
"""

from __future__ import annotations

import re

COUNTS_PER_GAUSS = 15_000
NT_PER_GAUSS = 100_000.0
NT_PER_COUNT = NT_PER_GAUSS / COUNTS_PER_GAUSS
RANGE_COUNTS = 30_000  # +-2 gauss
RATES_HZ = (10, 20, 25, 30, 40, 50, 60, 100, 123, 154)
SET_RESET_MODES = ("pulse", "auto", "off")
LINE_BYTES = 28
BITS_PER_LINE = LINE_BYTES * 10  # 8N1
BAUD_RATES = (9600, 19200)
BAUD_CODE = {9600: "S", 19200: "F"}  # *99!BR=S / *99!BR=F
BROADCAST_ID = 99
BAUD_SWITCH_S = 0.1  # ours: time given to the devices to change their rate (the notes give none)
FIELD_COLUMNS = ((0, 7), (9, 16), (18, 25))
SEPARATOR_COLUMNS = ((7, 9), (16, 18), (25, 27))
CR = b"\r"
ESC = b"\x1b"
# Replies, as the datasheet command table gives them (hardware-notes 2.3)
OK = b"OK\r"  # *ddWE, *ddR=nnn
ASCII_ON = b"ASCII_ON\r"  # *ddA
WRONG_ENTRY = b"Re-enter\r"
AUTO_SET_RESET_REPLY = {True: b"S/R_ON\r", False: b"S/R_OFF\r"}  # *ddTN / *ddTF
PULSE_REPLY = {1: b"SET\r", -1: b"RST\r"}
PULSE_COMMAND = {1: "]S", -1: "]R"}

_FIELD = re.compile(rb"([ -]) *(\d{1,2},\d{3}|\d{1,3})")


def command(device_id: int, body: str) -> bytes:
    """`*dd<body><CR>`."""
    return b"*%02d%s\r" % (device_id, body.encode("ascii"))


def baud_needed(rate_hz: int) -> int | None:
    """The lowest baud rate whose line carries an ASCII stream at `rate_hz`, None if neither does.
    The notes name 19200 for 40 and 50 Hz; the rest is the 280-bit line arithmetic (module docstring)."""
    return next((b for b in BAUD_RATES if rate_hz * BITS_PER_LINE <= b), None)


def decode_field(field: bytes) -> int | None:
    """One 7-byte signed count field, or None if it is not one."""
    m = _FIELD.fullmatch(field)
    if m is None:
        return None
    value = int(m.group(2).replace(b",", b""))
    return -value if m.group(1) == b"-" else value


def parse_sample_line(line: bytes) -> tuple[int, int, int] | None:
    """Counts from exactly one 28-byte sample line, or None if the line is malformed."""
    if len(line) != LINE_BYTES or not line.endswith(CR):
        return None
    if any(line[a:b] != b"  " for a, b in SEPARATOR_COLUMNS):
        return None
    counts = [decode_field(line[a:b]) for a, b in FIELD_COLUMNS]
    if None in counts:
        return None
    return counts[0], counts[1], counts[2]


def counts_to_nt(counts) -> tuple[float, float, float]:
    return tuple(c * NT_PER_COUNT for c in counts)


def half_sum_nt(reset, set_, reset_sign: int = 1) -> tuple[float, float, float]:
    """(set + reset_sign * reset) / 2 in nT: the bridge offset (+1) or the offset-free field (-1)."""
    return tuple((s + reset_sign * r) / 2 * NT_PER_COUNT for s, r in zip(set_, reset, strict=True))


def saturated(counts) -> frozenset[str]:
    return frozenset({"saturated"}) if any(abs(c) >= RANGE_COUNTS for c in counts) else frozenset()
