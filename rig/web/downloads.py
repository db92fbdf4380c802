"""What the cockpit offers for download, each made by the very code of the CLI command that writes it:

    calibration file, YAML or JSON      calib.io.calfile.save              (rig run, rig refit)
    C header, flight JSON, parameters   rig.report.exports.export_calibration  (rig export-cal)
    samples CSV                         rig.report.exports.write_samples_csv   (rig export)
    report                              rig.report.build.build_report   (rig report)

Calibrations are the fits the session recorded (the last one of each DUT and model). Files are made in the
server's own scratch folder, never beside the session.
"""

from __future__ import annotations

import io
import os
import shutil
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path

from rig.core.errors import DataError
from rig.session.reader import SessionReader

# kind -> (what the page calls it, file name ending, content type)
CALIBRATION_KINDS = {
    "cal-yaml": ("calibration file (YAML)", ".yaml", "application/yaml; charset=utf-8"),
    "cal-json": ("calibration file (JSON)", ".json", "application/json"),
    "c-header": ("C header", ".h", "text/x-c; charset=utf-8"),
    "flight-json": ("flight form (JSON)", ".flight.json", "application/json"),
    "params-csv": ("parameters (CSV)", ".params.csv", "text/csv; charset=utf-8"),
}
EXPORT_FORMAT = {"c-header": "c-header", "flight-json": "json", "params-csv": "csv"}
SAMPLES_KIND = "samples-csv"


@dataclass(frozen=True)
class Download:
    filename: str
    body: bytes
    content_type: str


def recorded_fits(reader: SessionReader) -> dict[tuple[str, str], dict]:
    """The last recorded fit of each (DUT, model)."""
    return {(f["dut"], f["model"]): f for f in reader.fits()}


def calibration(path: Path, dut: str, model: str):
    """The calibration of `dut` and `model` the session recorded (calib.calibration.Calibration)."""
    from calib.calibration import Calibration

    with SessionReader(path) as reader:
        fit = recorded_fits(reader).get((dut, model))
        if fit is None:
            raise DataError(f"{path.name}: no {model} fit of DUT {dut!r} recorded")
        recorded = reader.recorded_calibration(fit)
    return Calibration.from_dict(recorded, where=f"{path.name}: fit of {dut}")


def calibration_download(path: Path, kind: str, dut: str, model: str, scratch: Path) -> Download:
    from calib.io import calfile
    from rig.core.paths import calibration_file
    from rig.report.exports import export_calibration

    label, ending, content_type = CALIBRATION_KINDS[kind]
    cal = calibration(path, dut, model)
    filename = calibration_file(path, dut, model).name.removesuffix(".yaml") + ending
    if kind in EXPORT_FORMAT:
        return Download(filename, export_calibration(cal, EXPORT_FORMAT[kind], dut).encode(), content_type)
    with tempfile.TemporaryDirectory(dir=scratch) as tmp:
        target = Path(tmp) / f"cal{ending}"
        calfile.save(cal, target)
        return Download(filename, target.read_bytes(), content_type)


def samples_download(path: Path, dut: str) -> Download:
    """One DUT's unflagged samples, as `rig export SESSION --csv --dut DUT` writes them."""
    from rig.core.names import file_stem
    from rig.report.exports import write_samples_csv

    with SessionReader(path) as reader:
        dut, rows = reader.sample_rows(dut)
    text = io.StringIO(newline="")
    write_samples_csv(text, [r for r in rows if not r["flags"]])
    stem = path.name.removesuffix(".session")
    return Download(f"{stem}.{file_stem(dut)}.csv", text.getvalue().encode(), "text/csv; charset=utf-8")


REPORT_WAIT_S = 10.0  # a request waits this long for a report being built, then gets a page of its progress


class Reports:
    """HTML reports of sessions, built in a thread of their own on first request, in the scratch folder,
    and kept until the session file changes (a running campaign's report is of the points taken so far).
    A request waits `wait_s` for a build; a longer one (64 DUTs take most of a minute) answers with how far
    the build is, and the page asks again."""

    def __init__(self, scratch: Path, wait_s: float = REPORT_WAIT_S):
        self.scratch = scratch
        self.wait_s = wait_s
        self.lock = threading.Lock()
        self.builds: dict[Path, _Build] = {}

    def html(self, path: Path) -> bytes | str:
        """The report's page as bytes, or, while it is being built, a line saying how far it is. A build
        that failed raises its error here, once; the next request builds again."""
        key = _file_key(path)
        with self.lock:
            build = self.builds.get(path)
            if build is None or (build.key != key and not build.thread.is_alive()):
                if build is not None:
                    shutil.rmtree(build.folder, ignore_errors=True)
                build = self.builds[path] = _Build(path, key, Path(tempfile.mkdtemp(prefix="report-",
                                                                                    dir=self.scratch)))
        build.thread.join(self.wait_s)
        if build.thread.is_alive():
            return build.progress
        if build.error is not None:
            with self.lock:
                if self.builds.get(path) is build:
                    del self.builds[path]
            shutil.rmtree(build.folder, ignore_errors=True)
            raise build.error
        return build.page.read_bytes()


class _Build:
    """One report being built in a thread (rig.report.build.build_report), and what it has said."""

    def __init__(self, path: Path, key: tuple, folder: Path):
        self.path, self.key, self.folder = path, key, folder
        self.progress = "reading the session and fitting its DUTs"
        self.page: Path | None = None
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, name=f"report {path.name}", daemon=True)
        self.thread.start()

    def _run(self) -> None:
        from rig.report.build import build_report

        try:
            self.page = build_report(self.path, out_dir=self.folder, progress=self._said)
        except BaseException as exc:  # handed to the request that asks next
            self.error = exc

    def _said(self, message: str) -> None:
        self.progress = f"DUTs drawn: {message}"


def _file_key(path: Path) -> tuple:
    out = []
    for p in (path, Path(f"{path}-wal")):
        try:
            st = os.stat(p)
            out.append((st.st_mtime_ns, st.st_size))
        except OSError:
            out.append(None)
    return tuple(out)
