"""The reference chain, measured: how far each DUT's calibration is from the truth, depending on what the
rig knows of its reference, and whether the stated uncertainty covers the truth.

1. (a) / (b) / (c). One simulated campaign on a station whose coils really differ from their design (the
   station's `sim.coil_constants_nt_per_a`, `sim.coil_geometry`), with DUTs off the centre: the station
   is commissioned first (`rig commission`), the campaign runs, and each DUT is fitted three times on the
   SAME readings, with the reference field computed
     (a) from the declared constants, every DUT taken at the centre,
     (b) as the rig computed it: the commissioned matrix, the geometry and each DUT's position,
     (c) from the simulator's truth (matrix, geometry, true positions, true ambient);
   so that the readings' noise is common and only the reference differs. The figure is each DUT's
   held-out vector error: the RMS over a validation grid (other directions and magnitudes, temperatures
   between the plan's) of |calibrated field - true field|, the calibration applied to the raw reading the
   DUT's simulated truth gives there (noise-free: the calibration's own error). Goal: (b) <= 1.2 x (c).
   --chain-errors-from STATION.yaml adds that station's `sim.coil_loops` and `sim.current_source` (e.g.
   configs/stations/sim-lab.yaml's): (c) then takes the currents the source delivered (its read-back
   divided by the read-back's gain error) through every loop as it really is.

2. Coverage. Campaigns on randomised stations (true coil matrix ~1 % and ~0.3 deg off, loop sizes and
   spacings within their tolerance, DUTs at random positions up to +-70 mm with position errors within
   their tolerance, a reference magnetometer whose truth differs from its calibration file as its stated
   uncertainty allows, a drifting ambient), each commissioned, run and fitted with its uncertainty budget:
   the share of the true T24 parameters within the stated expanded uncertainty (U = k u), per parameter
   group and in all, and of the validation grid's true vector errors within `expanded_vector_error_nt`.
   Goal: 90-98 %.

    .venv/bin/python bench/reference_chain.py [--station STATION.yaml] [--plan PLAN.yaml]
                                              [--campaigns 7] [--duts 8] [--out DIR]
                                              [--chain-errors-from configs/stations/sim-lab.yaml]
    (--campaigns 0: part 1 alone)
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

import calib
from calib.calibration import Calibration
from calib.io import calfile
from calib.uncertainty.montecarlo import raw_for
from drivers.sim.world.coilfield import CoilGeometry, coil_matrix_at
from rig.budget import run_inputs as budget
from rig.commission.places import commission_place
from rig.commission.procedure import commission
from rig.config import load_station
from rig.config.loading import load_campaign
from rig.devices.simulated.world import dut_truths, true_position_m, world_deviations, world_field
from rig.run.campaign import run_campaign
from rig.session.reader import SessionReader

REPO = Path(__file__).resolve().parents[1]
STATION = REPO / "configs" / "stations" / "sim-commissioned.yaml"
PLAN = REPO / "configs" / "plans" / "demo.yaml"
SIM_CLOCK_START = 1_767_225_600.0  # drivers.clock.SimClock's start: the simulated ambient drifts from here
GROUPS = {"S": "S", "K": "K", "b": "b_nt", "kb": "kb_nt_per_c"}
CHAIN_ERRORS = ("coil_loops", "current_source")  # the world's keys --chain-errors-from copies
PLACES_MM = [(s * 70.0 * e).tolist() for e in np.eye(3) for s in (1, -1)]  # besides the centre


# --- a station ready to run: its files beside it, commissioned ------------------------------------------
def prepared(station_data: dict, source_dir: Path, out: Path, places=PLACES_MM) -> Path:
    """Write the station into `out` (its reference calibrations copied), commission it there (the reference
    at the centre, then at `places`: +-70 mm on each axis, the loops), and point it at its commissioning
    file."""
    data = copy.deepcopy(station_data)
    for ref in data.get("reference_magnetometers", []):
        cal = Path(ref["calibration"])
        target = out / cal.name
        target.write_text((cal if cal.is_absolute() else source_dir / cal).read_text())
        ref["calibration"] = cal.name
    data["field_source"].pop("commissioning", None)
    path = out / f"{data['name']}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    com = commission(path, out)
    for place in places:  # the loops, measured: the reference moved to each place in turn
        commission_place(path, out, place)
    data["field_source"]["commissioning"] = com.name
    data["field_source"]["max_age_days"] = 1.0
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def run(station_path: Path, plan_path: Path, out: Path) -> Path:
    session = out / "train.session"
    outcome = run_campaign(campaign=load_campaign(plan_path, station_path), session_path=session)
    assert outcome.result.status == "completed", outcome.result.reason
    return session


# --- the truth of a simulated station ---------------------------------------------------------------------
class Truth:
    """What the simulated world of a station is made of (the same keywords rig/devices/simulated/bench.py
    gives it)."""

    def __init__(self, station):
        world = world_field(station)
        self.station = station
        self.matrix = np.asarray(world["coil_constants_nt_per_a"], float)
        geometry = world.get("coil_geometry")
        self.geometry = None if geometry is None else CoilGeometry(*geometry)
        self.ambient = np.asarray(world["ambient_nt"], float)
        self.drift_per_s = np.asarray(world.get("ambient_drift_nt_per_s", np.zeros(3)), float)
        deviations = world_deviations(station.sim.model_dump())
        self.loops = deviations.get("coil_loops")
        source = deviations.get("current_source")
        self.readback_gain = 1.0 if source is None else 1.0 + np.asarray(source.readback_error_ppm) * 1e-6
        self.duts = dut_truths(station)

    def delivered_a(self, readback_a: np.ndarray) -> np.ndarray:
        """The currents that flowed, from the read-back ones the rig recorded (its noise aside)."""
        return readback_a / self.readback_gain

    def matrix_at(self, dut: str) -> np.ndarray:
        where = true_position_m(self.station, self.station.dut(dut))
        return coil_matrix_at(self.matrix, self.geometry, where, self.loops)

    def ambient_at(self, t: np.ndarray) -> np.ndarray:
        return self.ambient + np.outer(t - SIM_CLOCK_START, self.drift_per_s)

    def calibration(self, dut: str) -> Calibration:
        d = self.duts[dut]
        params = {"S": d.S, "K": d.K, "b_nt": d.b_nt, "kb_nt_per_c": d.kb_nt_per_c}
        return Calibration("t24", params, {k: np.zeros_like(v) for k, v in params.items()}, 0.0)


def validation_grid(temps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Directions and magnitudes the plan did not use, at temperatures between the plan's steps."""
    n = 40
    k = np.arange(n) + 0.5
    z = 1 - 2 * k / n
    phi = np.pi * (3 - np.sqrt(5)) * k + 0.3
    dirs = np.column_stack([np.sqrt(1 - z**2) * np.cos(phi), np.sqrt(1 - z**2) * np.sin(phi), z])
    fields = np.vstack([dirs * 30_000.0, dirs * 55_000.0])
    steps = np.unique(temps)
    between = (steps[:-1] + steps[1:]) / 2 if len(steps) > 1 else steps
    return np.repeat(fields, len(between), axis=0), np.tile(between, len(fields))


def heldout_error_nt(cal: Calibration, truth_cal: Calibration, grid) -> np.ndarray:
    """|calibrated - true| at every grid point, the raw readings the DUT's truth gives there."""
    fields, temps = grid
    h = raw_for(truth_cal, fields, temps)
    return np.linalg.norm(cal.apply(h, temps) - fields, axis=1)


# --- part 1 -----------------------------------------------------------------------------------------------
def with_chain_errors(base: dict, source: Path) -> dict:
    """The station with the coil loops and current source of `source`'s simulated world."""
    data = copy.deepcopy(base)
    data["name"] = f"{base['name']}-chain-errors"
    sim = yaml.safe_load(source.read_text())["sim"]
    data["sim"].update({key: copy.deepcopy(sim[key]) for key in CHAIN_ERRORS if key in sim})
    return data


def three_references(station_path: Path, plan_path: Path, out: Path) -> float:
    """Prints each DUT's three errors; returns the largest (b)/(c)."""
    session = run(station_path, plan_path, out)
    with SessionReader(session) as reader:
        inputs = budget.RunInputs.of_session(reader)
        station = inputs.station
        truth = Truth(station)
        declared = station.field_source.declared_constants
        print(f"  {'DUT':6s} {'position mm':>20s} {'(a) declared':>13s} {'(b) commissioned':>17s} "
              f"{'(c) truth':>10s} {'(b)/(c)':>8s}   expanded vector error (b) nT")
        worst = 0.0
        for dut in [d.name for d in station.duts]:
            ds, _ = inputs.refined(reader.dataset(dut))  # as the rig fits it: the run's best ambient
            chain = inputs.station.field_source.budget_chain(inputs, dut, ds)  # the currents of every sample
            grid = validation_grid(ds.temp_c)
            refs = {
                "a": chain.currents @ declared.T + chain.ambient,
                "b": ds.ref_nt,
                "c": truth.delivered_a(chain.currents) @ truth.matrix_at(dut).T
                     + truth.ambient_at(ds.columns["t"]),
            }
            errors = {}
            for key, ref in refs.items():
                cal = calib.fit(dataclasses.replace(ds, ref_nt=ref), "t24")
                error = heldout_error_nt(cal, truth.calibration(dut), grid)
                errors[key] = float(np.sqrt(np.mean(error**2)))
                if key == "b":
                    expanded = inputs.budget(dut, ds, cal).expanded_vector_error_nt
            ratio = errors["b"] / errors["c"]
            worst = max(worst, ratio)
            position = station.dut(dut).position_mm or (0, 0, 0)
            print(f"  {dut:6s} {str(tuple(position)):>20s} {errors['a']:13.1f} {errors['b']:17.2f} "
                  f"{errors['c']:10.2f} {ratio:8.2f}   {expanded:.1f}")
        print(f"  largest (b)/(c): {worst:.2f}   (goal <= 1.2)")
    return worst


# --- part 2 -----------------------------------------------------------------------------------------------
def random_station(base: dict, rng: np.random.Generator, n_duts: int, index: int) -> dict:
    data = copy.deepcopy(base)
    data["name"] = f"{base['name']}-random{index}"
    source = data["field_source"]
    declared = np.asarray(source["coil_constants_nt_per_a"], float)
    true = np.empty((3, 3))
    for j in range(3):
        axis = declared[:, j] / np.linalg.norm(declared[:, j])
        tilt = np.cross(axis, rng.normal(size=3))
        tilt *= np.radians(0.3) * abs(rng.normal(1.0, 0.3)) / np.linalg.norm(tilt)
        true[:, j] = np.linalg.norm(declared[:, j]) * (1 + rng.normal(0, 0.01)) * _rotate(axis, tilt)
    geometry = source["geometry"]
    tol_m = geometry.get("tolerance_mm", 1.0) / 1000.0
    sim = data.setdefault("sim", {})
    sim.update({
        "seed": int(rng.integers(1, 2**31)),
        "coil_constants_nt_per_a": true.round(3).tolist(),
        "coil_geometry": {"shape": geometry["shape"],
                          "size_m": [s + float(rng.uniform(-tol_m, tol_m)) for s in geometry["size_m"]],
                          "spacing_m": [s + float(rng.uniform(-tol_m, tol_m))
                                        for s in geometry["spacing_m"]]},
        "ambient_nt": (rng.normal(0, 1, 3) * [9000, 3000, 9000] + [16000, 0, 43000]).round(1).tolist(),
        "ambient_drift_nt_per_h": rng.normal(0, 15, 3).round(2).tolist(),
    })
    ref = data["reference_magnetometers"][0]
    ref_cal = calfile.load(STATION.parent / ref["calibration"])
    sim_duts = {name: spec for name, spec in sim.get("duts", {}).items() if name == ref["name"]}
    u = budget.standard_uncertainties(ref_cal)
    drawn = {k: (v + rng.normal(0, 1, np.shape(v)) * u[k]).tolist() for k, v in ref_cal.params.items()}
    sim_duts[ref["name"]] = {**sim_duts.get(ref["name"], {}), "truth": {
        **sim_duts.get(ref["name"], {}).get("truth", {}), **drawn}}
    duts, sensors, placed = [], [], []
    while len(duts) < n_duts:
        position = rng.uniform(-70, 70, 3).round(1)
        if np.linalg.norm(position) > 90 or any(np.linalg.norm(position - p) < 20 for p in placed):
            continue
        placed.append(position)
        name = f"dut{len(duts) + 1}"
        probe = f"tmp{len(duts) + 1}"
        duts.append({"name": name, "type": "mmc5983ma", "transport": {"kind": "sim"},
                     "options": {"bandwidth_hz": 100, "set_reset": True}, "temp_source": probe,
                     "position_mm": position.tolist(), "position_tolerance_mm": 1.0})
        sensors.append({"name": probe, "type": "tmp117", "transport": {"kind": "sim"}, "beside": name})
        sim_duts[name] = {"truth": "random", "noise_nt": 30, "thermal_lag_s": float(rng.uniform(300, 900)),
                          "position_error_mm": rng.uniform(-1.0, 1.0, 3).round(3).tolist()}
    data["duts"], data["temperature_sensors"] = duts, sensors
    sim["duts"] = sim_duts
    return data


def _rotate(axis: np.ndarray, rotation_vector: np.ndarray) -> np.ndarray:
    angle = np.linalg.norm(rotation_vector)
    k = rotation_vector / angle
    return axis * np.cos(angle) + np.cross(k, axis) * np.sin(angle) + k * (k @ axis) * (1 - np.cos(angle))


def coverage(base: dict, plan_path: Path, campaigns: int, n_duts: int, out: Path, seed: int = 7) -> None:
    rng = np.random.default_rng(seed)
    inside = {g: [] for g in GROUPS}
    vector_inside = []
    ratios = []
    for index in range(campaigns):
        folder = out / f"random{index}"
        folder.mkdir()
        station_path = prepared(random_station(base, rng, n_duts, index), STATION.parent, folder)
        start = time.perf_counter()
        session = run(station_path, plan_path, folder)
        with SessionReader(session) as reader:
            inputs = budget.RunInputs.of_session(reader)
            truth = Truth(inputs.station)
            for dut in [d.name for d in inputs.station.duts]:
                ds, _ = inputs.refined(reader.dataset(dut))
                cal = calib.fit(ds, "t24")
                b = inputs.budget(dut, ds, cal)
                true = truth.calibration(dut)
                for group, key in GROUPS.items():
                    off = np.abs(cal.params[key] - true.params[key])
                    inside[group] += list((off <= b.expanded[key]).ravel())
                errors = heldout_error_nt(cal, true, validation_grid(ds.temp_c))
                vector_inside += list(errors <= b.expanded_vector_error_nt)
                ratios.append(float(np.sqrt(np.mean(errors**2))) / b.combined_standard_nt)
        print(f"  campaign {index + 1}/{campaigns}: {n_duts} DUTs, {time.perf_counter() - start:.0f} s")
    total = np.concatenate([np.array(v) for v in inside.values()])
    print(f"  {campaigns * n_duts} DUTs; true parameters within the expanded uncertainty (U = k u):")
    for group, values in inside.items():
        print(f"    {group:3s} {np.mean(values):6.1%} of {len(values)}")
    print(f"    all {np.mean(total):6.1%} of {len(total)}   (goal 90-98 %)")
    print(f"  validation grid: true vector error within expanded_vector_error_nt at "
          f"{np.mean(vector_inside):.1%} of {len(vector_inside)} points; RMS true error / combined standard "
          f"uncertainty: median {np.median(ratios):.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--station", type=Path, default=STATION)
    parser.add_argument("--plan", type=Path, default=PLAN)
    parser.add_argument("--campaigns", type=int, default=7)
    parser.add_argument("--duts", type=int, default=8)
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--chain-errors-from", type=Path, default=None, metavar="STATION.yaml",
                        help="add this station's sim.coil_loops and sim.current_source")
    args = parser.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="magrig-reference-chain-"))
    base = yaml.safe_load(args.station.read_text())
    load_station(args.station)  # refuse a bad station file early, with its own error
    added = ""
    if args.chain_errors_from is not None:
        base = with_chain_errors(base, args.chain_errors_from)
        keys = [k for k in CHAIN_ERRORS if k in yaml.safe_load(args.chain_errors_from.read_text())["sim"]]
        added = f" with {', '.join(keys)} of {args.chain_errors_from.name}"
    print(f"reference chain on {args.station.name}{added}, plan {args.plan.name} (sessions in {out})")
    print("1. held-out vector error against the simulator's truth, nT (same readings, three references)")
    part1 = out / "three"
    part1.mkdir(parents=True)
    three_references(prepared(base, args.station.parent, part1), args.plan, part1)
    if args.campaigns > 0:
        print(f"2. coverage over {args.campaigns} randomised stations x {args.duts} DUTs")
        coverage(base, args.plan, args.campaigns, args.duts, out)


if __name__ == "__main__":
    main()
