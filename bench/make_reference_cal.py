"""Write a simulated reference magnetometer's calibration file from the truth its station states.

    python bench/make_reference_cal.py                      # configs/stations/sim-reference-cal.yaml
    python bench/make_reference_cal.py STATION.yaml NAME OUT.yaml
    python bench/make_reference_cal.py --certified   # configs/stations/sim-reference-cal-certified.yaml

`--certified` adds the calibration certificate the file transcribes (`source.certificate`: id, issuer,
date, U; rig/config/lab.py), which makes a station's chain traceable on its certificates: an example of
the keys, for sim-commissioned's ref0 (its issuer says it is fictitious; the station is simulated).

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
# U of the field up to 60 uT from those (k = 2): S's 4e-5 of 60 uT and b's 2 nT per axis, about 3 nT
EXAMPLE_CERTIFICATE = {
    "id": "EX-MAG-2026-0117", "date": "2026-01-01",
    "issuer": "Example Magnetometry Calibration Laboratory (fictitious: the simulated reference's "
              "certificate, to show the keys)",
    "expanded_uncertainty_nt": 3.0, "coverage_factor": 2.0, "coverage_probability": 0.9545,
    "scope": "fields up to 60 uT, 15 .. 35 degC",
    "issuer_accreditation": "accredited to ISO/IEC 17025 by a signatory of the ILAC MRA (example number "
                            "D-K-00000-00-00)",
    "route_to_si": "the issuer's proton-precession magnetometer, calibrated by its national metrology "
                   "institute against the tesla realised through the shielded proton's gyromagnetic ratio"}


def reference_calibration(station_path: Path, name: str, certificate: dict | None = None) -> Calibration:
    station = load_station(station_path)
    ref = next(r for r in station.reference_magnetometers if r.name == name)
    truth = reference_truths(station)[name]
    params = {"S": truth.S, "K": truth.K, "b_nt": truth.b_nt, "kb_nt_per_c": truth.kb_nt_per_c}
    std_errors = {k: np.full(np.shape(v), NOMINAL_SE[k]) for k, v in params.items()}
    return Calibration(
        model="t24", params={k: np.asarray(v, float) for k, v in params.items()}, std_errors=std_errors,
        temp_ref_c=25.0, source={"kind": "simulated truth", "station": station.name, "device": name,
                                 "device_type": ref.type,
                                 **({"certificate": certificate} if certificate else {})},
        software_version="bench/make_reference_cal.py", created_utc="2026-01-01T00:00:00Z",
        uncertainty=stated_uncertainty(params, std_errors, probability=(certificate or {}).get(
            "coverage_probability", 0.95)))


def stated_uncertainty(params: dict, std_errors: dict, k: float = 2.0, probability: float = 0.95) -> dict:
    """The `uncertainty:` section a certificate states: U = k u, the parameters independent (no
    covariance: the rig then takes diag((U / k)^2)); `probability` as the certificate words it."""
    return {"coverage_factor": k, "coverage_probability": probability,
            "method": "stated by the reference's calibration certificate (nominal, independent parameters)",
            "expanded": {name: (k * np.asarray(std_errors[name], float)).tolist() for name in params},
            "budget": [], "notes": []}


def main(argv: list[str]) -> None:
    if argv == ["--certified"]:
        out_path = STATIONS / "sim-reference-cal-certified.yaml"
        calfile.save(reference_calibration(STATIONS / "sim-commissioned.yaml", "ref0", EXAMPLE_CERTIFICATE),
                     out_path)
        print(f"wrote {out_path}")
        return
    station, name, out = (argv + [None] * 3)[:3]
    station_path = Path(station) if station else STATIONS / "sim-measured-ambient.yaml"
    out_path = Path(out) if out else STATIONS / "sim-reference-cal.yaml"
    calfile.save(reference_calibration(station_path, name or "sitefield"), out_path)
    print(f"wrote {out_path}")


if __name__ == "__main__":
    main(sys.argv[1:])
