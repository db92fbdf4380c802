"""The calibrations a session's run wrote, as the report shows them: each DUT's last recorded fit of each
model, with the file beside the session it was written to (its name and sha256), checked against the
session's own record of it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from calib.io.digest import sha256_file
from rig.core.errors import ERRORS


@dataclass
class Recorded:
    model: str
    calibration: object  # calib.Calibration
    file_name: str
    file_sha256: str | None  # None: no such file beside the session
    warning: str = ""  # the file differs from the session's record, or is gone

    def file_text(self) -> str:
        if self.file_sha256 is None:
            return f"{self.file_name} (not beside the session; shown from the session's record)"
        return f"{self.file_name} (sha256 {self.file_sha256})"


def recorded_calibrations(reader, dut: str) -> dict[str, Recorded]:
    """{model: Recorded} of one DUT, in the order the run fitted them; {} before the run's fits."""
    from calib.calibration import Calibration
    from calib.io import calfile
    from rig.core.paths import calibration_file

    last = {f["model"]: f for f in reader.fits() if f["dut"] == dut}
    out = {}
    for model, fit in last.items():
        try:
            cal = Calibration.from_dict(reader.recorded_calibration(fit),
                                        where=f"{reader.path.name}: recorded {model} fit of {dut}")
        except (*ERRORS, ValueError):
            continue
        path = calibration_file(reader.path, dut, model)
        entry = Recorded(model, cal, path.name, None)
        if Path(path).is_file():
            entry.file_sha256 = sha256_file(path)
            try:
                same = calfile.load(path).to_dict() == cal.to_dict()
            except ERRORS:
                same = False
            if not same:
                entry.warning = (f"{path.name} differs from the calibration the session recorded: the report "
                                 "shows the session's record")
        else:
            entry.warning = f"{path.name} is not beside the session: the report shows the session's record"
        out[model] = entry
    return out
