"""Independent simulated worlds for the uncertainty's coverage (bench/uncertainty.py): stations built from
configs/stations/sim-lab.yaml whose systematic errors are drawn afresh, from distributions wider than
what the station states for the budget to see: where the station states a tolerance +-a (the budget
takes a rectangular distribution, u = a / sqrt(3)), the world draws from a normal distribution of
standard deviation WIDER x u: larger and with tails beyond the stated bound (beyond +-a for 1 draw in 5).
`bench/uncertainty.py coverage --wider X` draws them at X x u instead, to see how the coverage falls where
a bench is worse than its station file says; `--table` puts a turntable in the coils' place (table_world).

What each station states (the budget's inputs) and what its world is drawn from:

- DUT position: stated +-1 mm; the world normal, WIDER x u per axis.
- coil geometry: stated sizes and spacings +-0.5 mm; the world normal, WIDER x u.
- coil loops: stated each loop +-0.5 mm, +-0.1 deg, +-1000 ppm; the world normal, WIDER x u each.
- ambient gradient: stated +-300 nT/m per component; the world symmetric and traceless, its five
  components normal, WIDER x u.
- reference magnetometer: stated its file's U (k = 2); its truth the file + N(0, WIDER u).
- current source: measured at commissioning (and +-200 ppm, +-0.3 mA stated); the world's gain,
  read-back and offset normal, WIDER x u.
- coil matrix: measured at commissioning; the world 1 % and 0.3 deg off the design.
- DUT beyond T24: the budget's model checks, misfit and wander; the world DutDeviations.random at a scale
  up to 2 (curvature, hysteresis, cubic) and slow offset noise up to 2x sim-lab's.
- ambient and chamber: measured during the run; the world's drift, steps and heater and compressor
  fields at 0 .. 1.5 x sim-lab's.

Nothing the budget reads is taken from `sim:`; the bench alone reads the truth back
(rig/devices/simulated/bench.py).
"""

from __future__ import annotations

import copy
import os
from pathlib import Path

import numpy as np
import yaml

from calib.calibration import standard_uncertainty
from calib.io import calfile
from calib.synthetic import random_t24_params
from drivers.sim.world.dutmodel import DutDeviations

REPO = Path(__file__).resolve().parents[1]
BASE = REPO / "configs" / "stations" / "sim-lab.yaml"
WIDER = 1.25
STATED = {"position_mm": 1.0, "geometry_mm": 0.5, "tilt_deg": 0.1, "turns_ppm": 1000.0, "gradient": 300.0,
          "gain_ppm": 200.0, "offset_ma": 0.3}
DUTS = 5


def _wider(rng, half, shape, wider):
    """A draw for a stated +-half: normal, `wider` x its rectangular standard uncertainty."""
    return rng.normal(0.0, wider * half / np.sqrt(3.0), shape)


def _gradient(rng, bound: float, wider: float) -> list[list[float]]:
    """A source-free gradient (symmetric, traceless): five independent components, each drawn as for a
    stated +-bound."""
    xx, yy, xy, xz, yz = _wider(rng, bound, 5, wider)
    return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, -xx - yy]]).round(1).tolist()


def _rotate(axis, angle_rad, rng) -> np.ndarray:
    tilt = np.cross(axis, rng.normal(size=3))
    tilt *= angle_rad / np.linalg.norm(tilt)
    k, a = tilt / np.linalg.norm(tilt), np.linalg.norm(tilt)
    return axis * np.cos(a) + np.cross(k, axis) * np.sin(a) + k * (k @ axis) * (1 - np.cos(a))


def _dut_truth(rng, scale: float) -> dict:
    p = random_t24_params(rng)
    dev = DutDeviations.random(rng, scale)
    return {"S": p["S"].round(6).tolist(), "K": p["K"].round(9).tolist(), "b_nt": p["b_nt"].round(2).tolist(),
            "kb_nt_per_c": p["kb_nt_per_c"].round(4).tolist(),
            "bridge_offset_nt": rng.normal(0, 2000, 3).round(1).tolist(),
            "bridge_offset_tc_nt_per_c": rng.normal(0, 20, 3).round(2).tolist(),
            "K2_per_c2": dev.K2_per_c2.round(11).tolist(),
            "kb2_nt_per_c2": dev.kb2_nt_per_c2.round(6).tolist(),
            "hysteresis": {"offset_nt": dev.hysteresis_offset_nt.round(2).tolist(), "band_c": 5.0},
            "cubic_ppm_at_50ut": dev.cubic_ppm_at_50ut.round(2).tolist()}


# families switched off for a diagnosis: "slow" (the DUTs' slow noise), "chamber", "hysteresis",
# "reference" (its truth exactly its calibration file), "position" (every DUT where the station says),
# "geometry" (the coils' sizes and spacings as drawn)
QUIET = set(filter(None, os.environ.get("MAGRIG_QUIET", "").split(",")))


def random_world(rng: np.random.Generator, index: int, reference_cal: Path, wider: float = WIDER) -> dict:
    """One station (as data) with its world drawn afresh (module docstring), its systematic errors `wider`
    x the standard uncertainties the station states."""

    def draw(half, shape=None):
        return _wider(rng, half, shape, wider)

    base = yaml.safe_load(BASE.read_text())
    data = copy.deepcopy(base)
    data["name"] = f"world{index:02d}"
    sim, source = data["sim"], data["field_source"]
    declared = np.asarray(source["coil_constants_nt_per_a"], float)
    true = np.empty((3, 3))
    for j in range(3):
        axis = declared[:, j] / np.linalg.norm(declared[:, j])
        true[:, j] = np.linalg.norm(declared[:, j]) * (1 + rng.normal(0, 0.01)) * _rotate(
            axis, np.radians(0.3) * abs(rng.normal(1.0, 0.3)), rng)
    geometry = source["geometry"]
    geometry.update(tolerance_mm=STATED["geometry_mm"], tilt_tolerance_deg=STATED["tilt_deg"],
                    turns_tolerance_ppm=STATED["turns_ppm"])
    tol_m = STATED["geometry_mm"] / 1000.0
    source["ambient_gradient_nt_per_m"] = STATED["gradient"]
    source["max_current_a"] = 2.5  # the demo's 50 uT against any ambient up to ambient_max_nt
    source["current_accuracy"] = {"gain_ppm": STATED["gain_ppm"], "offset_ma": STATED["offset_ma"]}
    source.pop("commissioning", None)
    world = rng.uniform(0.0, 1.5)  # the ambient's and the chamber's unkindness, x sim-lab's
    shape_off = 0.0 if "geometry" in QUIET else 1.0  # a family off is drawn all the same: the rest stay
    sim.update({
        "seed": int(rng.integers(1, 2**31)),
        "coil_constants_nt_per_a": true.round(3).tolist(),
        "coil_geometry": {"shape": geometry["shape"],
                          "size_m": [s + shape_off * float(draw(tol_m)) for s in geometry["size_m"]],
                          "spacing_m": [s + shape_off * float(draw(tol_m)) for s in geometry["spacing_m"]]},
        "coil_loops": {axis: {"turns_error_ppm": draw(STATED["turns_ppm"], 2).round(1).tolist(),
                              "offset_mm": draw(STATED["geometry_mm"], (2, 3)).round(3).tolist(),
                              "tilt_deg": draw(STATED["tilt_deg"], 2).round(4).tolist()}
                       for axis in "xyz"},
        "ambient_nt": (rng.normal(0, 1, 3) * [4000, 2000, 2500] + [16000, 0, 43000]).round(1).tolist(),
        "ambient_drift_nt_per_h": rng.normal(0, 5, 3).round(2).tolist(),
        "ambient_gradient_nt_per_m": _gradient(rng, STATED["gradient"], wider),
        "current_source": {
            "gain_error_ppm": draw(STATED["gain_ppm"], 3).round(1).tolist(),
            "offset_ma": draw(STATED["offset_ma"], 3).round(3).tolist(),
            "noise_ma": [0.1, 0.1, 0.1],
            "readback_error_ppm": draw(STATED["gain_ppm"], 3).round(1).tolist()},
    })
    if world > 0.05 and "chamber" not in QUIET:
        sim["ambient_steps"] = {"mean_interval_h": 2.0, "size_nt": round(30.0 * world, 1)}
        sim["chamber"] = {**base["sim"]["chamber"],
                          "heater_field_nt": (np.asarray(base["sim"]["chamber"]["heater_field_nt"]) * world)
                          .round(1).tolist(),
                          "compressor_field_nt": (np.asarray(base["sim"]["chamber"]["compressor_field_nt"])
                                                  * world).round(1).tolist()}
    else:
        sim.pop("ambient_steps", None)
        sim.pop("chamber", None)
    ref = data["reference_magnetometers"][0]
    ref_cal = calfile.load(reference_cal)
    off = 0.0 if "reference" in QUIET else 1.0
    place_off = 0.0 if "position" in QUIET else 1.0
    drawn = {name: (np.asarray(v, float) + off * rng.normal(0, 1, np.shape(v)) * wider
                    * standard_uncertainty(ref_cal.uncertainty, name)).tolist()
             for name, v in ref_cal.params.items()}
    duts, sensors, sim_duts, placed = [], [], {ref["name"]: {**sim["duts"][ref["name"]],
                                                             "truth": {**sim["duts"][ref["name"]]["truth"],
                                                                       **drawn}}}, []
    while len(duts) < DUTS:
        position = rng.uniform(-70, 70, 3).round(1)
        if np.linalg.norm(position) > 90 or any(np.linalg.norm(position - p) < 20 for p in placed):
            continue
        placed.append(position)
        name, probe = f"dut{len(duts) + 1}", f"tmp{len(duts) + 1}"
        duts.append({"name": name, "type": "mmc5983ma", "transport": {"kind": "sim"},
                     "options": {"bandwidth_hz": 100, "set_reset": True}, "temp_source": probe,
                     "position_mm": position.tolist(), "position_tolerance_mm": STATED["position_mm"]})
        sensors.append({"name": probe, "type": "tmp117", "transport": {"kind": "sim"}, "beside": name})
        scale = float(rng.uniform(0.3, 2.0))
        sim_duts[name] = {"truth": _dut_truth(rng, scale), "noise_nt": float(rng.uniform(20, 50)),
                          "thermal_lag_s": float(rng.uniform(300, 700)), "sensor_lag_s": 20,
                          "random_walk_nt_per_sqrt_h": round(2.0 * scale, 2),
                          "flicker_nt": round(15.0 * scale, 1),
                          "air_offset_c": round(float(rng.normal(0, 0.15)), 2),
                          "position_error_mm": (place_off * draw(STATED["position_mm"], 3)).round(3).tolist()}
    for name, spec in sim_duts.items():
        if name.startswith("dut") and "slow" in QUIET:
            spec["random_walk_nt_per_sqrt_h"] = spec["flicker_nt"] = 0.0
        if name.startswith("dut") and "hysteresis" in QUIET:
            spec["truth"]["hysteresis"]["offset_nt"] = [0.0, 0.0, 0.0]
    data["duts"], data["temperature_sensors"], sim["duts"] = duts, sensors, sim_duts
    return data


TABLE_FIELDS = {"kind": "grid", "az_deg": [0, 45, 90, 135, 180, 225, 270, 315], "el_deg": [-60, 0, 60]}


def table_world(data: dict, rng: np.random.Generator) -> dict:
    """The same world (lab, chamber, reference, DUTs on the table where they sat in the coils) with a
    two-axis turntable in place of the coils: its axes off the drawing (tilts and encoder zero offsets, which
    `rig commission` measures), the site field the coils' ambient was, measured at home by the reference;
    the stated gradient bound as for the coils."""
    data = copy.deepcopy(data)
    sim = data["sim"]
    for key in ("coil_constants_nt_per_a", "coil_geometry", "coil_loops", "current_source"):
        sim.pop(key, None)
    sim["site_field_nt"] = list(sim["ambient_nt"])
    sim["turntable_axes"] = {"az_tilt_deg": rng.normal(0, 0.2, 2).round(3).tolist(),
                             "el_tilt_deg": round(float(rng.normal(0, 0.2)), 3),
                             "zero_offsets_deg": rng.normal(0, 1.0, 2).round(3).tolist()}
    reference = data["reference_magnetometers"][0]["name"]
    data["field_source"] = {"kind": "turntable", "transport": {"kind": "sim"}, "rate_deg_s": 30,
                            "site_field": {"reference_magnetometer": reference},
                            "ambient_gradient_nt_per_m": STATED["gradient"]}
    return data
