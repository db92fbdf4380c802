"""What keeps `rig run` off POSIX-only paths, checked where it can be on any machine: Windows port names in
a station and a scan, signal handlers that are skipped where they cannot be set, the run lock's pid note
read in every form it is written in, no POSIX-only module imported on the way to a run."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from rig.config import load_station
from rig.core.errors import ConfigError
from rig.core.ports import check_port, port_key
from rig.core.signals import handled, name_of, set_handler
from rig.devices.scan import scan_targets
from rig.session.lock import SessionLock, holder_pid

REPO = Path(__file__).resolve().parents[3]
LAB = REPO / "configs" / "stations" / "lab-example.yaml"


@pytest.mark.parametrize("port", ["COM7", "com7", r"\\.\COM12", "/dev/ttyUSB0", "/dev/serial/by-id/usb-FTDI",
                                  "/dev/cu.usbserial-1420", "socket://127.0.0.1:7000", "loop://"])
def test_port_names_of_every_platform_are_accepted(port):
    assert check_port(port) == port


@pytest.mark.parametrize("port", ["", "ttyUSB0", " COM7", "COM0", "COM7 ", "my port"])
def test_a_name_that_is_no_port_is_refused(port):
    with pytest.raises(ValueError, match="not a serial port"):
        check_port(port)


def test_every_spelling_of_a_windows_port_is_one_port():
    assert {port_key(p) for p in ("COM7", "com7", r"\\.\COM7", r"\\.\com7")} == {"COM7"}
    assert port_key("COM17") != port_key("COM7")
    assert port_key("/dev/ttyUSB0") == "/dev/ttyUSB0"


def _lab_station(tmp_path, **replace) -> Path:
    text = LAB.read_text()
    for old, new in replace.items():
        assert old in text
        text = text.replace(old, new)
    path = tmp_path / "station.yaml"
    path.write_text(text)
    return path


def test_a_station_takes_windows_ports(tmp_path):
    path = _lab_station(tmp_path, **{"port: /dev/ttyUSB1": "port: COM7",
                                     "port: /dev/ttyUSB4": r"port: '\\.\COM12'",
                                     "port: /dev/ttyUSB0 ": "port: com3 "})
    ports = {d.name: getattr(d.transport, "port", None) for d in load_station(path).devices()}
    assert (ports["ser-c"], ports["sitefield"], ports["coils"]) == ("COM7", r"\\.\COM12", "com3")


def test_two_spellings_of_one_windows_port_are_one_line(tmp_path):
    path = _lab_station(tmp_path, **{"port: /dev/ttyUSB1": "port: COM1",
                                     "port: /dev/ttyUSB4": r"port: '\\.\com1'"})
    with pytest.raises(ConfigError, match=r"device id 0 on line COM1 is taken twice"):
        load_station(path)


def test_a_bad_port_names_file_key_and_line(tmp_path):
    path = _lab_station(tmp_path, **{"port: /dev/ttyUSB1": "port: ttyUSB1"})
    with pytest.raises(ConfigError) as err:
        load_station(path)
    message = str(err.value)
    assert message.startswith(f"{path}: duts[2].transport.port: 'ttyUSB1' is not a serial port")
    line = 1 + next(n for n, text in enumerate(path.read_text().splitlines()) if "port: ttyUSB1" in text)
    assert message.endswith(f"(line {line})") and "\n" not in message


def test_the_scan_takes_each_port_once_and_refuses_a_non_port():
    report = scan_targets(ports=[("COM250", 9600), (r"\\.\com250", 9600)], timeout_s=0.05)
    assert [p.port for p in report.ports] == ["COM250"]
    assert report.ports[0].error  # no such port on this machine: said, not raised
    with pytest.raises(ConfigError, match="--port: 'ttyUSB0' is not a serial port"):
        scan_targets(ports=[("ttyUSB0", 9600)])


def test_signal_handlers_outside_the_main_thread_or_platform_are_skipped():
    assert set_handler("SIGNOSUCH", lambda *_: None) is None
    seen = {}

    def in_a_thread():
        with handled({"SIGINT": lambda *_: None}) as names:
            seen["names"] = names

    thread = threading.Thread(target=in_a_thread)
    thread.start()
    thread.join()
    assert seen["names"] == []  # nothing set, nothing raised
    before = signal.getsignal(signal.SIGINT)
    with handled({"SIGINT": lambda *_: None, "SIGNOSUCH": lambda *_: None}) as names:
        assert names == ["SIGINT"] and signal.getsignal(signal.SIGINT) is not before
    assert signal.getsignal(signal.SIGINT) is before
    assert name_of(signal.SIGTERM.value) == "SIGTERM"


@pytest.mark.parametrize("note, pid", [("\n4242\n", 4242), ("4242\n", 4242), ("4242\nhost\n123\n", 4242),
                                       ("", None), ("\n\n", None), ("x\n", None), ("0\n", None)])
def test_the_lock_note_is_read_in_every_form(tmp_path, note, pid):
    Path(f"{tmp_path / 's.session'}.lock").write_text(note)
    assert holder_pid(tmp_path / "s.session") == pid


def test_a_held_lock_names_this_process_and_leaves_nothing_behind(tmp_path):
    with SessionLock(tmp_path / "s.session") as lock:
        assert lock.held and holder_pid(tmp_path / "s.session") == os.getpid()
    assert not lock.held and list(tmp_path.iterdir()) == []


def test_no_bus_or_pty_module_on_the_way_to_a_run():
    """What `rig run` imports before it opens a device: not smbus2 (fcntl at its import) nor the pty
    simulator's modules. (fcntl and termios may come, each behind a guard, with filelock and pymodbus:
    tests/system/test_no_posix_run.py runs without them.)"""
    code = ("import sys\nimport rig.run.campaign, rig.cli.campaign_cmds, rig.devices.simulated.bench\n"
            "import rig.devices.scan\n"
            "import rig.config.station, drivers.registry\ndrivers.registry.specs('magnetometer')\n"
            "print(' '.join(sorted({'pty', 'tty', 'smbus2', 'drivers.sim.transports.pty'}"
            " & set(sys.modules))))")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == ""
