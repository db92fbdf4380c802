"""Continuous ramp against step-and-dwell on the same simulated station (configs/stations/sim-4.yaml: four
MMC5983MA DUTs, element lags 300..900 s behind the air, TMP117 probes lagging the element by 60..240 s,
random T24 truths with non-zero K and kb).

For each plan: simulated chamber hours; each DUT's held-out vector error (RMS |B_cal - B_ref|, nT) on a
separate validation session at temperatures between the steps; for the ramp, with and without the lag
correction, and the lag estimates against the simulator's sensor_lag_s. Goal: ramp <= 40 % of the step
plan's chamber time with a held-out error <= 1.1 x the step plan's.

    .venv/bin/python bench/ramp_vs_step.py [--out DIR]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

import calib
from rig.analysis.lagfit import lag_corrected
from rig.config.loading import load_campaign
from rig.devices.simulated.world import dut_truths
from rig.run.campaign import run_campaign
from rig.session.reader import SessionReader, read_dataset

REPO = Path(__file__).resolve().parents[1]
STATION = REPO / "configs" / "stations" / "sim-4.yaml"
STEPS = [-30, -15, 0, 15, 25, 40, 55, 70]
BETWEEN = [-22.5, -7.5, 7.5, 20, 32.5, 47.5, 62.5]  # validation temperatures, between the steps
FIELDS = {"kind": "cube24", "magnitudes_nt": [30000, 60000]}
STABILITY = {"band_c": 0.3, "rate_c_per_min": 0.05, "dwell_s": 600, "max_wait_s": 10800}
START = {"band_c": 1.0, "rate_c_per_min": 0.2, "dwell_s": 120}  # the ramp only needs to start near -30

PLANS = {
    "step": {"temperatures": {"steps": STEPS, "ramp_c_per_min": 2.0, "stability": STABILITY},
             "fields": FIELDS, "samples_per_point": 10, "settle_s": 1.0},
    "ramp": {"temperatures": {"mode": "ramp", "range_c": [-30, 70], "rate_c_per_min": 2.0, "cycles": 1,
                              "end_hold_s": 600, "stability": START},
             "fields": FIELDS, "samples_per_point": 2, "settle_s": 3.0},
    "validation": {"temperatures": {"steps": BETWEEN, "ramp_c_per_min": 3.0, "stability": STABILITY},
                   "fields": {"kind": "fibonacci", "n": 20, "magnitude_nt": 45000},
                   "samples_per_point": 4, "settle_s": 1.0},
}


def run(name: str, out: Path) -> Path:
    plan = {"name": name, **PLANS[name], "fit": {"models": ["t24"]}}
    path = out / f"{name}.yaml"
    path.write_text(yaml.safe_dump(plan, sort_keys=False))
    session = out / f"{name}.session"
    start = time.perf_counter()
    outcome = run_campaign(campaign=load_campaign(path, STATION), session_path=session)
    assert outcome.result.status == "completed", outcome.result.reason
    print(f"  {name}: {outcome.result.points_done} points in {time.perf_counter() - start:.0f} s wall")
    return session


def chamber_hours(session: Path) -> float:
    with SessionReader(session) as reader:
        info = reader.info()
    return (info["ended"] - info["started"]) / 3600.0


def held_out_nt(cal, validation: Path, dut: str, truth) -> tuple[float, float]:
    """RMS vector error on the validation rows: against the recorded reference (the readings' noise
    included), and against the simulator's truth for the same raw readings (the calibration's own error;
    the validation is taken at stable temperatures, where the probe reads the element's)."""
    ds = read_dataset(validation, dut)
    calibrated = cal.apply(ds.h_nt, ds.temp_c)
    true = np.array([truth.field_from_raw(h, t) for h, t in zip(ds.h_nt, ds.temp_c, strict=True)])
    return tuple(float(np.sqrt(np.mean(np.sum((calibrated - x) ** 2, axis=1)))) for x in (ds.ref_nt, true))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, help="keep the sessions here (default: a temporary folder)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp)
        out.mkdir(parents=True, exist_ok=True)
        print(f"station {STATION.name}; running the three sessions:")
        sessions = {name: run(name, out) for name in PLANS}
        stated = yaml.safe_load(STATION.read_text())["sim"]["duts"]
        truths = dut_truths(load_campaign(out / "step.yaml", STATION).station)
        hours = {name: chamber_hours(sessions[name]) for name in ("step", "ramp")}
        print(f"\nchamber time: step {hours['step']:.2f} h, ramp {hours['ramp']:.2f} h "
              f"({hours['ramp'] / hours['step']:.0%} of the step plan's; goal <= 40 %)")
        print("\nheld-out vector error, RMS nT: against the validation reference (noise included) / "
              "against the simulator's truth (the calibration's own error)")
        head = f"{'DUT':5} {'lag truth':>9} {'lag estimate':>14} {'step':>13} {'ramp+lag':>13}"
        print(f"{head} {'ramp raw':>13}  ratio")
        ratios = []
        for dut in stated:
            step_cal = calib.fit(read_dataset(sessions["step"], dut), "t24")
            raw = read_dataset(sessions["ramp"], dut)
            corrected, lag = lag_corrected(raw)
            errors = [held_out_nt(c, sessions["validation"], dut, truths[dut])
                      for c in (step_cal, calib.fit(corrected, "t24"), calib.fit(raw, "t24"))]
            ratios.append(errors[1][0] / errors[0][0])
            estimate = (f"{lag['tau_s']:.0f} +- {lag['tau_se_s']:.0f} s" if lag.get("tau_s") is not None
                        else "none")
            print(f"{dut:5} {stated[dut]['sensor_lag_s']:>7.0f} s {estimate:>14} "
                  + " ".join(f"{a:6.1f} /{b:5.1f}" for a, b in errors) + f"  {ratios[-1]:.2f}")
            for warning in lag.get("warnings", []):
                print(f"      warning: {warning}")
        print(f"\nworst held-out ratio ramp+lag / step (against the reference): {max(ratios):.2f} "
              "(goal <= 1.1)")


if __name__ == "__main__":
    main()
