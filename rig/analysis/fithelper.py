"""The post-run fits of many DUTs on two cores: a helper process, and how the run's process shares the
DUTs with it.

    with run_helper(session_path, models, robust, len(duts)) as helper:   # as the run starts
        ...                                                                   # the run
        for dut, results in fitted_duts(session_path, models, robust, duts, started, helper):
            ...                                      # [DutFit] as each DUT's fits end (any order)

With HELPER_MIN_FITS fits or more and two cores, the helper takes DUTs from the end of the list while the
run's process fits them from the front (rig/analysis/dutfits.py); they meet in the middle. The helper is a
fresh interpreter started on this module, never a copy of the run's process: a fork would copy the
hardware threads mid-flight, and multiprocessing's spawn would run again whatever script started the
campaign. Whatever the helper cannot do (it failed to start, or died) is fitted in the run's process;
MAGRIG_POSTRUN_HELPER=0 in the environment keeps every fit there. A helper started with the run
(run_helper) imports what the fits use while the run goes on, so that the fits find it ready; without one,
fitted_duts starts it itself.

    python -m rig.analysis.fithelper SESSION MODELS ROBUST     # MODELS "t24,p12"; ROBUST 0 or 1

It reads DUT names, one a line, on its standard input; for each it fits every model (writing the
calibration files) and answers on its standard output with the pickled [DutFit] (8-byte length first).
It ends when its input ends, so a run's process that dies for any reason takes it along. It runs in a
process group of its own: Ctrl-C at the terminal is the run's to handle, and never reaches it. Pickle is safe
here: both ends are this program, over a pipe only they hold.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import queue
import struct
import subprocess
import sys
import tempfile
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import rig
from rig.analysis.dutfits import DutFit, SessionFits

HELPER_MIN_FITS = 16  # below this a helper's start-up (about a second) costs more than it saves
IN_FLIGHT = 2  # DUTs handed to the helper at a time: it never idles, and never holds many
LENGTH = struct.Struct(">Q")
SILENT_S = 300.0  # one DUT's fits take a fraction of a second; this long without an answer is a hang


def main(argv: list[str]) -> int:
    session, models, robust = argv
    # What the fits use is imported before the first DUT arrives: a helper started with the run has it
    # ready by the run's end. The session is opened at the first DUT, once the run has recorded it all.
    from calib.io import calfile  # noqa: F401
    from rig.analysis import sessionfit, tempchoice  # noqa: F401
    from rig.reference import chain_record  # noqa: F401

    out = sys.stdout.buffer
    fits: SessionFits | None = None
    try:
        for line in sys.stdin:
            fits = fits or SessionFits(session, tuple(models.split(",")), robust == "1")
            payload = pickle.dumps(fits.fit(line.strip()), protocol=pickle.HIGHEST_PROTOCOL)
            out.write(LENGTH.pack(len(payload)) + payload)
            out.flush()
    finally:
        if fits is not None:
            fits.close()
    return 0


class Helper:
    """The run's end: give(dut), then results() as they come; `alive` False once it has ended or failed
    (its stderr is kept in a file and said in the log)."""

    def __init__(self, proc: subprocess.Popen, errors):
        self.proc, self.errors = proc, errors
        self.alive = True
        self._done: queue.Queue = queue.Queue()
        self._reader = threading.Thread(target=self._read, name="fit helper", daemon=True)
        self._reader.start()

    @staticmethod
    def wanted(fits: int) -> bool:
        """Whether `fits` post-run fits are worth a helper on this machine."""
        return fits >= HELPER_MIN_FITS and (os.cpu_count() or 1) >= 2 \
            and os.environ.get("MAGRIG_POSTRUN_HELPER") != "0"

    @classmethod
    def start(cls, session_path, models, robust: bool) -> Helper | None:
        """The helper started on `session_path`, or None where no process can be had."""
        code = str(Path(rig.__file__).resolve().parents[1])  # this very code, installed or not
        path = os.pathsep.join(filter(None, [code, os.environ.get("PYTHONPATH")]))
        env = {**os.environ, "PYTHONPATH": path, "OPENBLAS_NUM_THREADS": "1"}  # one core is its share
        errors = tempfile.TemporaryFile()
        try:
            proc = subprocess.Popen([sys.executable, "-m", "rig.analysis.fithelper", str(session_path),
                                     ",".join(models), "1" if robust else "0"],
                                    stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=errors, env=env,
                                    process_group=0)
        except OSError:
            errors.close()
            return None
        return cls(proc, errors)

    def give(self, dut: str) -> None:
        try:
            self.proc.stdin.write(f"{dut}\n".encode())
            self.proc.stdin.flush()
        except OSError:  # it has ended: the reader says so
            self.alive = False

    def results(self, block: bool):
        """(dut, fits) for every answer there is; with `block`, waits for one, or for the helper's end (a
        helper silent for SILENT_S is taken for hung: stopped, and `alive` False)."""
        while True:
            try:
                fits = self._done.get(block=block and self.alive, timeout=SILENT_S if block else None)
            except queue.Empty:
                if block and self.alive:
                    self.alive = False
                    self.proc.kill()
                return
            if fits is None:
                self.alive = False
                return
            yield fits[0].dut, fits
            block = False

    def _read(self) -> None:
        stream = self.proc.stdout
        try:
            while head := stream.read(LENGTH.size):
                fits = pickle.loads(stream.read(LENGTH.unpack(head)[0]))
                self._done.put(fits)
        except (OSError, EOFError, pickle.UnpicklingError, struct.error):
            pass
        self._done.put(None)

    def close(self) -> None:
        """Input closed (it ends), waited for; a failure of its own logged with its last words."""
        import logging

        try:
            self.proc.stdin.close()
        except OSError:
            pass
        # its output ends as it exits: the reader's join wakes at that moment, where a wait with a timeout
        # would poll in growing sleeps
        self._reader.join(timeout=60)
        if self._reader.is_alive():
            self.proc.kill()
        code = self.proc.wait()
        self.errors.seek(0)
        said = self.errors.read().decode(errors="replace").strip().splitlines()
        self.errors.close()
        if code != 0:
            last = said[-1] if said else "no message"
            logging.getLogger("magrig.postrun").warning(
                "post-run fits: the helper process ended with code %s (%s); its DUTs were fitted here",
                code, last)

    def __enter__(self) -> Helper:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# --- many DUTs ----------------------------------------------------------------------------------------
@contextlib.contextmanager
def run_helper(session_path: str | Path, models: tuple[str, ...], robust: bool, duts: int):
    """A helper started with a run, for its post-run fits (None where it is not worth one): it loads what
    the fits use while the run goes on. Give it to fitted_duts; it ends with the block."""
    helper = Helper.start(session_path, models, robust) if Helper.wanted(duts * len(models)) else None
    if helper is None:
        yield None
        return
    with helper:
        yield helper


def fitted_duts(session_path: str | Path, models: tuple[str, ...], robust: bool, duts: list[str],
                started: Callable[[str], None], helper: Helper | None = None
                ) -> Iterator[tuple[str, list[DutFit]]]:
    """(dut, its fits) for every DUT as they end; `started(dut)` is told as each DUT's fits begin.
    `helper`: one started with the run (run_helper), else one is started here where it is worth it."""
    with SessionFits(session_path, models, robust) as here:
        if helper is not None:
            yield from _fitted(here, helper, duts, started)
            return
        with run_helper(session_path, models, robust, len(duts)) as own:  # None where not worth one
            yield from _fitted(here, own, duts, started)


def _fitted(here: SessionFits, helper: Helper | None, duts: list[str],
            started: Callable[[str], None]) -> Iterator[tuple[str, list[DutFit]]]:
    if helper is None or not helper.alive:
        for dut in duts:
            started(dut)
            yield dut, here.fit(dut)
        return
    yield from _shared_out(here, helper, list(duts), started)


def _shared_out(here: SessionFits, helper: Helper, duts: list[str],
                started: Callable[[str], None]) -> Iterator[tuple[str, list[DutFit]]]:
    """This process fits from the front, the helper from the back; a DUT the helper fails is fitted here."""
    given: list[str] = []  # handed to the helper, not yet back
    while duts or given:
        while helper.alive and len(given) < IN_FLIGHT and len(duts) > 1:
            dut = duts.pop()
            started(dut)
            given.append(dut)
            helper.give(dut)
        if duts:
            dut = duts.pop(0)
            started(dut)
            yield dut, here.fit(dut)
        # wait for the helper only when nothing is left to fit here and it holds some
        for dut, fits in helper.results(block=not duts and bool(given)):
            given.remove(dut)
            yield dut, fits
        if not helper.alive:  # what it held is fitted here
            while given:
                dut = given.pop(0)
                yield dut, here.fit(dut)


if __name__ == "__main__":
    exit_code = main(sys.argv[1:])
    sys.stdout.flush()
    os._exit(exit_code)  # everything is written and closed: the interpreter's teardown is time the run waits
