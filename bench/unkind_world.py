"""What each of the simulated world's departures from the rig's models costs a calibration.

The demo plan on configs/stations/sim-lab.yaml (every deviation on, at hardware-notes §9 sizes), and on
copies of it keeping only one family of deviations (and one keeping none: T24 DUTs with white noise, the
pair-level coil truth, a drifting uniform ambient, an ideal chamber and current source). Each station is
commissioned, run, and every DUT fitted (T24) as the rig fits it. Per variant, the mean over its DUTs of
- the fit's residual RMS (nT), and
- the held-out vector error against the simulator's truth (nT): RMS over a validation grid (other
  directions and magnitudes, temperatures between the plan's) of |calibrated - true field|, the
  calibration applied to the raw reading the DUT's truth gives there (noise-free; its hysteresis and slow
  noise at zero), and
- the expanded (k = 2) vector uncertainty the rig states for it.

    .venv/bin/python bench/unkind_world.py [--station configs/stations/sim-lab.yaml] [--out DIR]
                                           [--only all,none,...]
(about 30 s per variant)
"""

from __future__ import annotations

import argparse
import copy
import tempfile
from pathlib import Path

import numpy as np
import yaml

import calib
from bench.reference_chain import PLAN, prepared, run, validation_grid
from rig.budget import run_inputs as budget
from rig.devices.simulated.world import dut_truths
from rig.session.reader import SessionReader

REPO = Path(__file__).resolve().parents[1]
STATION = REPO / "configs" / "stations" / "sim-lab.yaml"
WORLD_KEYS = ("current_source", "coil_loops", "ambient_gradient_nt_per_m", "ambient_steps", "chamber")
TRUTH_KEYS = ("K2_per_c2", "kb2_nt_per_c2", "hysteresis", "cubic_ppm_at_50ut")
NOISE_KEYS = ("random_walk_nt_per_sqrt_h", "flicker_nt")
VARIANTS = {  # name: (what it keeps, the deviation keys it keeps)
    "none": ("none", ()),
    "dut": ("DUT beyond T24 (K2, kb2, hysteresis, cubic)", TRUTH_KEYS),
    "noise": ("offset random walk and flicker", NOISE_KEYS),
    "air": ("DUT places off the air (air_offset_c)", ("air_offset_c",)),
    "loops": ("coil loops", ("coil_loops",)),
    "current": ("current source", ("current_source",)),
    "ambient": ("ambient gradient and steps", ("ambient_gradient_nt_per_m", "ambient_steps")),
    "chamber": ("chamber (rate, overshoot, heater, compressor)", ("chamber",)),
    "all": ("all", WORLD_KEYS + TRUTH_KEYS + NOISE_KEYS + ("air_offset_c",)),
}


def variant(base: dict, keep: tuple[str, ...], name: str) -> dict:
    """The station with every deviation key not in `keep` removed."""
    data = copy.deepcopy(base)
    data["name"] = f"{base['name']}-{name}"
    sim = data["sim"]
    for key in WORLD_KEYS:
        if key not in keep:
            sim.pop(key, None)
    for dut in sim["duts"].values():
        for key in NOISE_KEYS + ("air_offset_c",):
            if key not in keep:
                dut.pop(key, None)
        truth = dut.get("truth")
        if isinstance(truth, dict):
            for key in TRUTH_KEYS:
                if key not in keep:
                    truth.pop(key, None)
    return data


def figures(session: Path) -> tuple[float, float, float]:
    residual, heldout, expanded = [], [], []
    with SessionReader(session) as reader:
        inputs = budget.RunInputs.of_session(reader)
        truths = dut_truths(inputs.station)
        for dut in [d.name for d in inputs.station.duts]:
            ds, _ = inputs.refined(reader.dataset(dut))  # as the rig fits it: the run's best ambient
            cal = calib.fit(ds, "t24")
            fields, temps = validation_grid(ds.temp_c)
            truth = truths[dut]
            h = np.array([truth.raw_from_field(f, t) for f, t in zip(fields, temps, strict=True)])
            error = np.linalg.norm(cal.apply(h, temps) - fields, axis=1)
            residual.append(cal.stats["rms_after_nt"])
            heldout.append(float(np.sqrt(np.mean(error**2))))
            expanded.append(inputs.budget(dut, ds, cal).expanded_vector_error_nt)
    return float(np.mean(residual)), float(np.mean(heldout)), float(np.mean(expanded))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--station", type=Path, default=STATION)
    parser.add_argument("--plan", type=Path, default=PLAN)
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--only", default=",".join(VARIANTS), help=f"some of {','.join(VARIANTS)}")
    args = parser.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="magrig-unkind-world-"))
    base = yaml.safe_load(args.station.read_text())
    print(f"{args.plan.name} on {args.station.name} and its variants (sessions in {out}); T24, DUT mean")
    print(f"  {'deviations kept':46s} {'residual nT':>11s} {'held-out vs truth':>18s} {'stated U':>9s}")
    for name in args.only.split(","):
        what, keep = VARIANTS[name]
        folder = out / name
        folder.mkdir(parents=True)
        station = prepared(variant(base, keep, name), args.station.parent, folder)
        residual, heldout, expanded = figures(run(station, args.plan, folder))
        print(f"  {what:46s} {residual:11.1f} {heldout:18.1f} {expanded:9.1f}")


if __name__ == "__main__":
    main()
