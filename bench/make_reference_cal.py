"""Write a simulated reference magnetometer's calibration file from the truth its station states.

    python bench/make_reference_cal.py                      # configs/stations/sim-reference-cal.yaml
    python bench/make_reference_cal.py STATION.yaml NAME OUT.yaml

A reference's simulated truth IS its calibration (rig/devices/simulated/bench.py reference_truths), so the
file is the truth in the T24 form (absolute-tau convention), with small nominal standard errors and the
uncertainty a calibration certificate of such a reference would state (k = 2, from those standard errors): a
reference calibration without an uncertainty is refused by the rig.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from calib.calibration import Calibration
from calib.io import calfile
from rig.config import load_station
from rig.devices.simulated.world import reference_truths

STATIONS = Path(__file__).resolve().parent.parent / "configs" / "stations"
NOMINAL_SE = {"S": 2e-5, "K": 1e-7, "b_nt": 1.0, "kb_nt_per_c": 0.02}  # what a good coil calibration gives


def reference_calibration(station_path: Path, name: str) -> Calibration:
    station = load_station(station_path)
    ref = next(r for r in station.reference_magnetometers if r.name == name)
    truth = reference_truths(station)[name]
    params = {"S": truth.S, "K": truth.K, "b_nt": truth.b_nt, "kb_nt_per_c": truth.kb_nt_per_c}
    std_errors = {k: np.full(np.shape(v), NOMINAL_SE[k]) for k, v in params.items()}
    return Calibration(
        model="t24", params={k: np.asarray(v, float) for k, v in params.items()}, std_errors=std_errors,
        temp_ref_c=25.0, source={"kind": "simulated truth", "station": station.name, "device": name,
                                 "device_type": ref.type},
        software_version="bench/make_reference_cal.py", created_utc="2026-01-01T00:00:00Z",
        uncertainty=stated_uncertainty(params, std_errors))


def stated_uncertainty(params: dict, std_errors: dict, k: float = 2.0) -> dict:
    """The `uncertainty:` section a certificate states: U = k u, the parameters independent (no
    covariance: the rig then takes diag((U / k)^2))."""
    return {"coverage_factor": k, "coverage_probability": 0.95,
            "method": "stated by the reference's calibration certificate (nominal, independent parameters)",
            "expanded": {name: (k * np.asarray(std_errors[name], float)).tolist() for name in params},
            "budget": [], "notes": []}


def main(argv: list[str]) -> None:
    station, name, out = (argv + [None] * 3)[:3]
    station_path = Path(station) if station else STATIONS / "sim-measured-ambient.yaml"
    out_path = Path(out) if out else STATIONS / "sim-reference-cal.yaml"
    calfile.save(reference_calibration(station_path, name or "sitefield"), out_path)
    print(f"wrote {out_path}")


if __name__ == "__main__":
    main(sys.argv[1:])
