"""Write a simulated reference magnetometer's calibration file from the truth its station states.

    python bench/make_reference_cal.py                      # configs/stations/sim-reference-cal.yaml
    python bench/make_reference_cal.py STATION.yaml NAME OUT.yaml

A reference's simulated truth IS its calibration (rig/devices/bench.py reference_truths), so the file is the
truth in the T24 form (absolute-tau convention), with small nominal standard errors.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from calib import calfile
from calib.calibration import Calibration
from rig.config import load_station
from rig.devices.bench import reference_truths

STATIONS = Path(__file__).resolve().parent.parent / "configs" / "stations"
NOMINAL_SE = {"S": 2e-5, "K": 1e-7, "b_nt": 1.0, "kb_nt_per_c": 0.02}  # what a good coil calibration gives


def reference_calibration(station_path: Path, name: str) -> Calibration:
    station = load_station(station_path)
    ref = next(r for r in station.reference_magnetometers if r.name == name)
    truth = reference_truths(station)[name]
    params = {"S": truth.S, "K": truth.K, "b_nt": truth.b_nt, "kb_nt_per_c": truth.kb_nt_per_c}
    return Calibration(
        model="t24", params={k: np.asarray(v, float) for k, v in params.items()},
        std_errors={k: np.full(np.shape(v), NOMINAL_SE[k]) for k, v in params.items()},
        temp_ref_c=25.0, source={"kind": "simulated truth", "station": station.name, "device": name,
                                 "device_type": ref.type},
        software_version="bench/make_reference_cal.py", created_utc="2026-01-01T00:00:00Z")


def main(argv: list[str]) -> None:
    station, name, out = (argv + [None] * 3)[:3]
    station_path = Path(station) if station else STATIONS / "sim-measured-ambient.yaml"
    out_path = Path(out) if out else STATIONS / "sim-reference-cal.yaml"
    calfile.save(reference_calibration(station_path, name or "sitefield"), out_path)
    print(f"wrote {out_path}")


if __name__ == "__main__":
    main(sys.argv[1:])
