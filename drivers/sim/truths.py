"""The simulator's defaults and the simulated DUTs' truths, from what a station states (plain data).

A random truth is drawn from default_rng([seed, position of the DUT in the station]), so changing one DUT
leaves the others' truths alone; an explicit truth is taken as given (absolute-tau T24 convention).
"""

from __future__ import annotations

import numpy as np

from drivers.sim.world import DutTruth

NOISE_NT = 20.0  # white noise per axis, RMS
THERMAL_LAG_S = 600.0  # DUT temperature time constant against the chamber air
AIR_C = 22.0  # chamber air at the start
CHAMBER_RAMP_C_PER_MIN = 3.0  # the fastest the simulated chamber's air moves (heater and compressor)
TRUTH_KEYS = ("S", "K", "b_nt", "kb_nt_per_c", "bridge_offset_nt", "bridge_offset_tc_nt_per_c")


def dut_truth(seed: int, position: int, truth: dict | str = "random", noise_nt: float | None = None,
              thermal_lag_s: float | None = None) -> DutTruth:
    """`truth`: "random", or a mapping with S and optionally the other TRUTH_KEYS (zero when absent)."""
    noise = NOISE_NT if noise_nt is None else noise_nt
    lag = THERMAL_LAG_S if thermal_lag_s is None else thermal_lag_s
    if truth == "random":
        return DutTruth.random(np.random.default_rng([seed, position]), noise_nt=noise, thermal_lag_s=lag)
    assert isinstance(truth, dict)
    values = {k: np.asarray(truth[k], float) for k in TRUTH_KEYS if truth.get(k) is not None}
    values.setdefault("K", np.zeros((3, 3)))
    for key in ("b_nt", "kb_nt_per_c"):
        values.setdefault(key, np.zeros(3))
    return DutTruth(**values, noise_nt=noise, thermal_lag_s=lag)


def mount_truth(thermal_lag_s: float | None = None) -> DutTruth:
    """A place on the bench with a temperature but no sensor errors: where a simulated probe sits beside
    a real DUT (the world has no truth for a real DUT)."""
    lag = THERMAL_LAG_S if thermal_lag_s is None else thermal_lag_s
    return DutTruth(S=np.eye(3), K=np.zeros((3, 3)), b_nt=np.zeros(3), kb_nt_per_c=np.zeros(3),
                    thermal_lag_s=lag)
