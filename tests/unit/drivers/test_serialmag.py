"""Transcript tests of the HMR2300 serial magnetometer: literal bytes sent and replied.

Every command and reply below is spelled out from the datasheet command table in hardware-notes 2.3
(`*ddWE` -> `OK`, `*ddR=nnn` -> `OK`, `*ddTN`/`TF` -> `S/R_ON`/`S/R_OFF`, `*dd]S`/`]R` -> `SET`/`RST`,
`*ddA` -> `ASCII_ON`, `*99!BR=F` for 19200 baud, `Re-enter` for a wrong entry), not from the driver.
The serial number and firmware lines are our simulator's text (the notes give no format for them)."""

from __future__ import annotations

import logging

import pytest

from drivers.errors import DeviceTimeout, OptionError, ProtocolError
from drivers.serialmag import SerialMagnetometer, baud_needed, parse_sample_line
from drivers.sim.devices.serialmag import format_sample_line
from tests.unit.drivers.test_serial_transport import ScriptedPort, scripted_transport

# X = 12,345 Y = -1,234 Z = 567 counts: sign byte, 6-byte magnitude, two spaces per axis, CR.
SAMPLE = b" 12,345  - 1,234      567  \r"

CONNECT_PULSE_MODE = [
    (b"\x1b", b""),  # Esc: stop a stream left running
    (b"*00A\r", b"ASCII_ON\r"),
    (b"*00WE\r", b"OK\r"),
    (b"*00TF\r", b"S/R_OFF\r"),
    (b"*00WE\r", b"OK\r"),
    (b"*00R=20\r", b"OK\r"),
    (b"*00]S\r", b"SET\r"),
    (b"*00#\r", b"SM2300-0001\r"),
    (b"*00F\r", b"SM2300 fw 1.4\r"),
]
CONNECT_AUTO_MODE = [
    (b"\x1b", b""),
    (b"*00A\r", b"ASCII_ON\r"),
    (b"*00WE\r", b"OK\r"),
    (b"*00TN\r", b"S/R_ON\r"),
    (b"*00WE\r", b"OK\r"),
    (b"*00R=20\r", b"OK\r"),
    (b"*00#\r", b"SM2300-0001\r"),
    (b"*00F\r", b"SM2300 fw 1.4\r"),
]


def connected(transcript, connect=CONNECT_PULSE_MODE, **kwargs):
    port = ScriptedPort(list(connect) + list(transcript))
    mag = SerialMagnetometer(scripted_transport(port), name="dut2", **kwargs)
    mag.connect()
    return mag, port


def test_sample_line_layout_is_28_bytes_and_decodes_to_exact_counts():
    assert len(SAMPLE) == 28
    assert parse_sample_line(SAMPLE) == (12345, -1234, 567)
    assert parse_sample_line(b"      0  -30,000   30,000  \r") == (0, -30000, 30000)


def test_simulator_formats_the_same_literal_line():
    assert format_sample_line((12345, -1234, 567)) == SAMPLE
    assert format_sample_line((0, -30000, 9)) == b"      0  -30,000        9  \r"


@pytest.mark.parametrize(
    "line",
    [
        b" 12,345  - 1,234      567\r",  # no trailing spaces: 26 bytes
        b"+12,345  - 1,234      567  \r",  # '+' is not a sign byte
        b"  12345  - 1,234      567  \r",  # no thousands comma
        b" 12,345 - 1,234       567  \r",  # separator moved
        b" 12,3p5  - 1,234      567  \r",  # flipped digit
        b" 12,345  - 1,234      567  \n",  # wrong terminator
    ],
)
def test_malformed_lines_are_rejected(line):
    assert parse_sample_line(line) is None


def test_connect_transcript_and_describe():
    mag, port = connected([])
    assert port.transcript == []
    info = mag.describe()
    assert info["serial_number"] == "SM2300-0001" and info["firmware"] == "SM2300 fw 1.4"
    assert info["counts_per_gauss"] == 15000 and info["range_nt"] == 200_000.0


def test_poll_decodes_counts_and_nt_in_auto_mode():
    mag, _ = connected([(b"*00P\r", SAMPLE)], connect=CONNECT_AUTO_MODE, set_reset="auto")
    sample = mag.read()
    assert sample.counts == (12345, -1234, 567)
    assert sample.field_nt == pytest.approx((82_300.0, -8226.6667, 3780.0))
    assert sample.offset_nt is None and sample.temp_c is None and not sample.flags


def test_set_reset_read_cancels_the_bridge_offset():
    mag, port = connected(
        [
            (b"*00]R\r", b"RST\r"),
            (b"*00P\r", b"- 1,000    2,000  - 3,000  \r"),
            (b"*00]S\r", b"SET\r"),
            (b"*00P\r", b"  1,500    2,600  - 2,400  \r"),
        ]
    )
    sample = mag.read()
    assert port.transcript == []
    # H = (set - reset)/2 = (1250, 300, 300) counts; offset = (set + reset)/2 = (250, 2300, -2700) counts
    assert sample.field_nt == pytest.approx((8333.333, 2000.0, 2000.0))
    assert sample.offset_nt == pytest.approx((1666.667, 15333.333, -18000.0))
    assert sample.counts == (1500, 2600, -2400)


def test_device_id_goes_into_every_command():
    connect = [(c.replace(b"*00", b"*05"), r) for c, r in CONNECT_AUTO_MODE]
    mag, port = connected([(b"*05P\r", SAMPLE)], connect=connect, set_reset="auto", device_id=5)
    assert mag.read().counts == (12345, -1234, 567)


def test_rate_is_write_enabled_and_checked_before_writing():
    mag, port = connected([(b"*00WE\r", b"OK\r"), (b"*00R=30\r", b"OK\r")])
    mag.set_rate(30)
    assert mag.rate_hz == 30 and port.writes[-2:] == [b"*00WE\r", b"*00R=30\r"]
    sent = len(port.writes)
    with pytest.raises(OptionError, match="dut2: rate_hz 33 is not one of 10, 20, 25"):
        mag.set_rate(33)
    with pytest.raises(OptionError, match=r"dut2: rate_hz 154: a 28-byte ASCII .* needs 43120 baud"):
        mag.set_rate(154)
    assert len(port.writes) == sent


def test_rates_that_need_19200_baud():
    # the notes: 19200 for 40 and 50 Hz; 60 Hz by the 280-bit line arithmetic; 100 Hz and up: neither
    assert [baud_needed(r) for r in (10, 20, 25, 30, 40, 50, 60, 100, 123, 154)] == [
        9600, 9600, 9600, 9600, 19200, 19200, 19200, None, None, None,
    ]


def test_a_rate_that_needs_19200_switches_every_device_on_the_line_first():
    mag, port = connected(
        [
            (b"*99WE\r", b""),  # id 99: every device, no reply awaited
            (b"*99!BR=F\r", b""),
            (b"*00A\r", b"ASCII_ON\r"),  # the device answers at the new rate
            (b"*00WE\r", b"OK\r"),
            (b"*00R=50\r", b"OK\r"),
        ]
    )
    mag.set_rate(50)
    assert port.write_bauds[-5:] == [9600, 9600, 19200, 19200, 19200]
    assert mag.transport.baudrate == 19200 and port.transcript == []


def test_connect_finds_a_device_left_at_19200_baud():
    connect = [(b"\x1b", b""), *[(b"*00A\r", b"")] * 3, *CONNECT_AUTO_MODE[1:]]
    port = ScriptedPort(connect)
    mag = SerialMagnetometer(scripted_transport(port), name="dut2", set_reset="auto")
    mag.connect()
    assert port.write_bauds[:5] == [9600, 9600, 9600, 9600, 19200] and port.transcript == []


@pytest.mark.parametrize(
    ("call", "sent", "operation"),
    [
        (lambda m: m.set_rate(25), b"*00R=25\r", "set rate"),
        (lambda m: m.pulse(-1), b"*00]R\r", "reset pulse"),
        (lambda m: m.pulse(1), b"*00]S\r", "set pulse"),
    ],
)
def test_re_enter_ends_in_a_protocol_error_naming_the_command(call, sent, operation):
    we = [(b"*00WE\r", b"OK\r")] if sent.startswith(b"*00R") else []
    mag, _ = connected([*we, (sent, b"Re-enter\r")] * 3)
    with pytest.raises(ProtocolError) as err:
        call(mag)
    assert str(err.value) == (
        f"dut2: {operation}: device answered Re-enter (command refused) to {sent!r} (after 3 tries)"
    )
    assert mag.rate_hz == 20


def test_re_enter_at_connect_is_a_protocol_error():
    start = [(b"\x1b", b""), (b"*00A\r", b"ASCII_ON\r")]
    port = ScriptedPort(start + [(b"*00WE\r", b"OK\r"), (b"*00TF\r", b"Re-enter\r")] * 3)
    mag = SerialMagnetometer(scripted_transport(port), name="dut2")
    with pytest.raises(ProtocolError, match=r"^dut2: set auto set/reset: device answered Re-enter"):
        mag.connect()


def test_a_generic_ok_is_not_the_datasheet_reply_to_tf():
    start = [(b"\x1b", b""), (b"*00A\r", b"ASCII_ON\r")]
    port = ScriptedPort(start + [(b"*00WE\r", b"OK\r"), (b"*00TF\r", b"OK\r")] * 3)
    mag = SerialMagnetometer(scripted_transport(port), name="dut2")
    with pytest.raises(ProtocolError, match=r"expected b'S/R_OFF\\r' after b'\*00TF\\r', got b'OK\\r'"):
        mag.connect()


def test_noise_before_a_sample_is_dropped_and_logged(caplog):
    mag, _ = connected([(b"*00P\r", b"\x00\xfe#@" + SAMPLE)], connect=CONNECT_AUTO_MODE, set_reset="auto")
    with caplog.at_level(logging.WARNING, logger="magrig.drivers.serialmag"):
        assert mag.read().counts == (12345, -1234, 567)
    assert "dropped 4 noise bytes" in caplog.text
    assert caplog.records[0].device == "dut2"


def test_malformed_reply_is_discarded_and_the_poll_repeated(caplog):
    mag, port = connected(
        [(b"*00P\r", b" 12,3\r"), (b"*00P\r", SAMPLE)], connect=CONNECT_AUTO_MODE, set_reset="auto"
    )
    with caplog.at_level(logging.WARNING):
        assert mag.read().counts == (12345, -1234, 567)
    assert "discarded malformed line b' 12,3\\r'" in caplog.text
    assert port.writes[-2:] == [b"*00P\r", b"*00P\r"]


def test_silent_device_ends_in_device_timeout_naming_device_and_operation():
    mag, _ = connected([(b"*00P\r", b"")] * 3, connect=CONNECT_AUTO_MODE, set_reset="auto")
    with pytest.raises(DeviceTimeout, match=r"^dut2: poll sample: no reply within 0.01 s \(after 3 tries\)$"):
        mag.read()


def test_stream_collects_n_samples_skips_junk_and_stops_with_esc():
    lines = (
        b"      1        2        3  \r"
        b"#!\r"  # junk line: discarded
        b"-     4        5  -     6  \r"
        b"xx      7        8        9  \r"  # noise before a valid line: kept
        b"     10       11       12  \r"  # more than asked for: dropped with the stream tail
    )
    mag, port = connected([(b"*00C\r", lines), (b"\x1b", b"")], connect=CONNECT_AUTO_MODE, set_reset="auto")
    samples = mag.read_stream(3)
    assert [s.counts for s in samples] == [(1, 2, 3), (-4, 5, -6), (7, 8, 9)]
    assert port.writes[-1] == b"\x1b" and port.transcript == []


def test_stream_in_pulse_mode_subtracts_the_measured_offset():
    mag, port = connected(
        [
            (b"*00]R\r", b"RST\r"),
            (b"*00P\r", b"-   900  - 1,100      100  \r"),
            (b"*00]S\r", b"SET\r"),
            (b"*00P\r", b"  1,100      900      300  \r"),
            (b"*00C\r", b"  1,150      950      250  \r"),
            (b"\x1b", b""),
        ]
    )
    (sample,) = mag.read_stream(1)
    # offset = (set + reset)/2 = (100, -100, 200) counts, subtracted from the streamed (1150, 950, 250)
    assert sample.offset_nt == pytest.approx((2000 / 3, -2000 / 3, 4000 / 3))
    assert sample.field_nt == pytest.approx((7000.0, 7000.0, 1000 / 3))


def test_stream_gives_up_after_bad_lines_in_a_row_and_still_stops():
    mag, port = connected(
        [(b"*00C\r", b"bad\rbad\rbad\r"), (b"\x1b", b"")], connect=CONNECT_AUTO_MODE, set_reset="auto"
    )
    with pytest.raises(ProtocolError, match=r"dut2: stream samples: malformed line b'bad\\r' \(3 failures"):
        mag.read_stream(5)
    assert port.writes[-1] == b"\x1b"


def test_saturated_reading_is_flagged():
    mag, _ = connected(
        [(b"*00P\r", b" 30,000        0        0  \r")], connect=CONNECT_AUTO_MODE, set_reset="auto"
    )
    assert mag.read().flags == {"saturated"}


def test_safe_state_never_raises_on_a_dead_port(caplog):
    dead = ScriptedPort(fail_with=OSError(5, "Input/output error"))
    mag = SerialMagnetometer(scripted_transport(dead), name="dut2")
    with caplog.at_level(logging.WARNING, logger="magrig.drivers.serialmag"):
        mag.safe_state()  # the write fails: port lost
        mag.safe_state()  # the port cannot even be opened now
    assert not mag.transport.is_open
    assert "Input/output error" in caplog.records[0].message
    assert "cannot open /dev/ttyFAKE0" in caplog.records[1].message


def test_bad_settings_are_config_errors():
    transport = scripted_transport()
    with pytest.raises(OptionError, match="dut2: device_id 99 is not in 0..98"):
        SerialMagnetometer(transport, name="dut2", device_id=99)
    with pytest.raises(OptionError, match="dut2: baudrate 115200: the HMR2300 runs at 9600 or 19200 only"):
        SerialMagnetometer.from_port("/dev/null", name="dut2", baudrate=115200)
    with pytest.raises(OptionError, match="dut2: set_reset 'sometimes'"):
        SerialMagnetometer(transport, name="dut2", set_reset="sometimes")


@pytest.mark.parametrize("set_reset, mode",
                         [("pulse", "set_reset_pair"), ("off", "set_only"), ("auto", "single")])
def test_describe_states_how_a_reading_is_made(set_reset, mode):
    """The reading's mode follows the SET/RESET setting; the stated conversion is the driver's counts to nT
    (15000 counts a gauss)."""
    from drivers.serialmag_protocol import counts_to_nt
    from tests.helpers.conversion import stated_nt

    mag = SerialMagnetometer(scripted_transport(ScriptedPort([])), name="dut2", set_reset=set_reset)
    reading = mag.reading()
    assert reading["mode"] == mode and reading["raw_unit"] == "nT"
    for counts in (-30000, -1, 0, 12345, 30000):
        expected = counts_to_nt((counts,) * 3)[0]
        assert stated_nt(reading["conversion"], counts) == pytest.approx(expected, abs=1e-9)
