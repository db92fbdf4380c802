"""A station's `sim:` made into the simulated world: the one place where what a station states of the
simulator's truth (rig/config/sim.py) becomes a World (drivers/sim/world/), with the simulator's defaults
where the station states nothing.

    world = make_world(station, clock)

A random DUT truth is drawn from default_rng([seed, position of the DUT in the station]), so changing one
DUT leaves the others' truths alone; an explicit truth is taken as given (absolute-tau T24 convention, plus
the deviations beyond it: drivers/sim/world/dutmodel.py). `world_deviations` turns the station's
world-level deviation keys into the World's keywords; every key left out (or zero) leaves the world as it
was. The field source's field is the `sim:` truth over what the station declares (`world_field`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from drivers.clock import Clock
from drivers.sim.world import DutTruth, World
from drivers.sim.world.chamberair import ChamberTruth
from drivers.sim.world.coilfield import LoopErrors
from drivers.sim.world.currentsource import CurrentSourceErrors
from drivers.sim.world.dutmodel import DutDeviations
from rig.fieldsources.fieldmaths import TYPICAL_FIELD_NT

NOISE_NT = 20.0  # white noise per axis, RMS
THERMAL_LAG_S = 600.0  # DUT temperature time constant against the chamber air
AIR_C = 22.0  # chamber air at the start
CHAMBER_RAMP_C_PER_MIN = 3.0  # the fastest the simulated chamber's air moves (heater and compressor)
TRUTH_KEYS = ("S", "K", "b_nt", "kb_nt_per_c", "bridge_offset_nt", "bridge_offset_tc_nt_per_c")
DEVIATION_KEYS = ("K2_per_c2", "kb2_nt_per_c2", "hysteresis", "cubic_ppm_at_50ut")
DUT_KEYS = ("random_walk_nt_per_sqrt_h", "flicker_nt", "air_offset_c")  # beside the truth, per DUT
AXES = ("x", "y", "z")


def dut_truth(seed: int, position: int, truth: dict | str = "random", noise_nt: float | None = None,
              thermal_lag_s: float | None = None, **beside: float) -> DutTruth:
    """`truth`: "random", or a mapping with S and optionally the other TRUTH_KEYS (zero when absent) and
    DEVIATION_KEYS; `beside`: DUT_KEYS (the offset's slow noise, the place's air offset)."""
    noise = NOISE_NT if noise_nt is None else noise_nt
    lag = THERMAL_LAG_S if thermal_lag_s is None else thermal_lag_s
    if truth == "random":
        out = DutTruth.random(np.random.default_rng([seed, position]), noise_nt=noise, thermal_lag_s=lag)
    else:
        assert isinstance(truth, dict)
        values = {k: np.asarray(truth[k], float) for k in TRUTH_KEYS if truth.get(k) is not None}
        values.setdefault("K", np.zeros((3, 3)))
        for key in ("b_nt", "kb_nt_per_c"):
            values.setdefault(key, np.zeros(3))
        out = DutTruth(**values, noise_nt=noise, thermal_lag_s=lag, deviations=dut_deviations(truth))
    for key, value in beside.items():
        if key not in DUT_KEYS:
            raise TypeError(f"dut_truth: unknown key {key!r}")
        setattr(out, key, float(value))
    return out


def dut_deviations(truth: dict) -> DutDeviations | None:
    """The truth's departures from T24 (None when it states none, or only zeros)."""
    hysteresis = truth.get("hysteresis") or {}
    dev = DutDeviations(
        K2_per_c2=np.asarray(truth.get("K2_per_c2", np.zeros((3, 3))), float),
        kb2_nt_per_c2=np.asarray(truth.get("kb2_nt_per_c2", np.zeros(3)), float),
        hysteresis_offset_nt=np.asarray(hysteresis.get("offset_nt", np.zeros(3)), float),
        cubic_ppm_at_50ut=np.asarray(truth.get("cubic_ppm_at_50ut", np.zeros(3)), float),
    )
    if "band_c" in hysteresis:
        dev.hysteresis_band_c = float(hysteresis["band_c"])
    return None if dev.is_zero() else dev


def mount_truth(thermal_lag_s: float | None = None) -> DutTruth:
    """A place on the bench with a temperature but no sensor errors: where a simulated probe sits beside
    a real DUT (the world has no truth for a real DUT)."""
    lag = THERMAL_LAG_S if thermal_lag_s is None else thermal_lag_s
    return DutTruth(S=np.eye(3), K=np.zeros((3, 3)), b_nt=np.zeros(3), kb_nt_per_c=np.zeros(3),
                    thermal_lag_s=lag)


def world_deviations(sim: dict) -> dict:
    """World keywords from the station's `sim:` block (as plain data): the chamber's real rate and
    behaviour, the current source, the coil loops, the ambient's gradient and steps."""
    chamber = sim.get("chamber") or {}
    rate = chamber.get("max_rate_c_per_min")
    out: dict = {"ramp_c_per_min": CHAMBER_RAMP_C_PER_MIN if rate is None else float(rate)}
    if chamber:
        out["chamber"] = ChamberTruth(overshoot_c=float(chamber["overshoot_c"]),
                                      heater_field_nt=tuple(chamber["heater_field_nt"]),
                                      compressor_field_nt=tuple(chamber["compressor_field_nt"]))
    if sim.get("current_source"):
        out["current_source"] = CurrentSourceErrors(**{k: tuple(v) for k, v in sim["current_source"].items()})
    if sim.get("coil_loops"):
        out["coil_loops"] = {
            j: LoopErrors(turns_error_ppm=tuple(loop["turns_error_ppm"]),
                          offset_m=tuple(tuple(x / 1000.0 for x in o) for o in loop["offset_mm"]),
                          tilt_deg=tuple(loop["tilt_deg"]))
            for j, loop in enumerate(sim["coil_loops"][axis] for axis in AXES)}
    if sim.get("ambient_gradient_nt_per_m") is not None:
        out["ambient_gradient_nt_per_m"] = np.asarray(sim["ambient_gradient_nt_per_m"], float)
    steps = sim.get("ambient_steps")
    if steps:
        out["ambient_steps"] = (float(steps["mean_interval_h"]), float(steps["size_nt"]))
    return out


def dut_truths(station) -> dict[str, DutTruth]:
    """{DUT name: truth} for the simulated DUTs, from the station's `sim.duts` (defaults applied)."""
    out = {}
    for position, dut in enumerate(station.duts):
        if not dut.simulated:
            continue
        spec = station.sim.duts.get(dut.name)
        if spec is None:
            out[dut.name] = dut_truth(station.sim.seed, position)
        else:
            truth: Any = spec.truth if spec.truth == "random" else spec.truth.model_dump()
            out[dut.name] = dut_truth(station.sim.seed, position, truth, spec.noise_nt, spec.thermal_lag_s,
                                      **spec.model_dump(include=set(DUT_KEYS)))
            out[dut.name].sensor_lag_s = spec.sensor_lag_s
        out[dut.name].position_m = true_position_m(station, dut)
    return out


def true_position_m(station, device) -> np.ndarray:
    """Where a simulated sensor really sits (m): its stated position_mm plus sim.duts' position_error_mm."""
    stated = np.zeros(3) if device.position_mm is None else np.asarray(device.position_mm, float)
    spec = station.sim.duts.get(device.name)
    error = np.zeros(3) if spec is None else np.asarray(spec.position_error_mm, float)
    return (stated + error) / 1000.0


def reference_truths(station) -> dict[str, DutTruth]:
    """{name: truth} of the simulated reference magnetometers. A reference's calibration file is its
    truth, so it is never drawn at random: `sim.duts` states it (S, b_nt...) to match the shipped file,
    or it is an ideal sensor (what an identity calibration file describes)."""
    out = {}
    for ref in station.reference_magnetometers:
        if not ref.simulated:
            continue
        spec = station.sim.duts.get(ref.name)
        beside = {} if spec is None else spec.model_dump(include=set(DUT_KEYS))  # as a DUT's
        if spec is None or spec.truth == "random":
            out[ref.name] = dut_truth(station.sim.seed, 0, {"S": np.eye(3)},
                                      None if spec is None else spec.noise_nt,
                                      None if spec is None else spec.thermal_lag_s, **beside)
        else:
            out[ref.name] = dut_truth(station.sim.seed, 0, spec.truth.model_dump(), spec.noise_nt,
                                      spec.thermal_lag_s, **beside)
        out[ref.name].position_m = true_position_m(station, ref)
    return out


def world_field(station) -> dict:
    """The simulated field source's keywords: the station's `sim:` truth where it states one, else what
    the station declares (else a typical field)."""
    sim = station.sim
    out = station.field_source.declared_world()
    truth = {"ambient_nt": sim.ambient_nt, "site_field_nt": sim.site_field_nt,
             "coil_constants_nt_per_a": sim.coil_constants_nt_per_a,
             "coil_geometry": None if sim.coil_geometry is None else
             (sim.coil_geometry.shape, tuple(sim.coil_geometry.size_m), tuple(sim.coil_geometry.spacing_m))}
    for key, value in truth.items():
        if key in out and value is not None:
            out[key] = value if key == "coil_geometry" else np.asarray(value, float)
    for key in ("ambient_nt", "site_field_nt"):
        if key in out and out[key] is None:
            out[key] = np.asarray(TYPICAL_FIELD_NT, float)
    out["coil_nonlinearity_per_a"] = np.asarray(sim.coil_nonlinearity_per_a, float)
    axes = sim.turntable_axes
    out["turntable_axes"] = None if axes is None else (tuple(axes.az_tilt_deg), axes.el_tilt_deg,
                                                       tuple(axes.zero_offsets_deg))
    if sim.ambient_drift_nt_per_h is not None:  # nT/h in the station, nT/s in the world
        out["ambient_drift_nt_per_s"] = np.asarray(sim.ambient_drift_nt_per_h, float) / 3600.0
    return out


def make_world(station, clock: Clock) -> World:
    """The station's world: its field source's field, its deviations, its
    DUTs."""
    air_c = AIR_C if station.sim.air_c is None else station.sim.air_c
    world = World(clock, air_c=air_c, seed=station.sim.seed, **world_field(station),
                  **world_deviations(station.sim.model_dump()))
    for name, truth in (dut_truths(station) | reference_truths(station)).items():
        world.add_dut(name, truth)
    for sensor in station.temperature_sensors:
        if sensor.simulated and sensor.beside not in world.duts:
            world.add_dut(sensor.beside, mount_truth())
    return world
