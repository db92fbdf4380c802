"""The simulator's defaults and the simulated DUTs' truths, from what a station states (plain data).

A random truth is drawn from default_rng([seed, position of the DUT in the station]), so changing one DUT
leaves the others' truths alone; an explicit truth is taken as given (absolute-tau T24 convention, plus
the deviations beyond it: drivers/sim/world/dutmodel.py). `world_deviations` turns the station's world-level
deviation keys into the World's keywords; every key left out (or zero) leaves the world as it was.
"""

from __future__ import annotations

import numpy as np

from drivers.sim.world.chamberair import ChamberTruth
from drivers.sim.world.coilfield import LoopErrors
from drivers.sim.world.currentsource import CurrentSourceErrors
from drivers.sim.world.dutmodel import DutDeviations, DutTruth

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
