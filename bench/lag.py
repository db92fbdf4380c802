"""Thermal-lag estimation on synthetic ramp series: bias, spread against the stated standard error, time.

For each true lag (element lags the recorded air, 1 degC/min ramps -20..60 degC, one sample every 10 s,
10 nT noise), over several seeds: mean estimate and its error, the scatter of the estimates against the
mean profile-curvature standard error (a ratio near 1 means the stated uncertainty is honest), the
up/down T24 disagreement before and after the correction, and the time per estimate. Also the
sensor-lags case with direction="auto".

    .venv/bin/python bench/lag.py [--seeds 10]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from calib.synthetic import t24_ramp_dataset
from calib.thermal.lag import estimate_lag


def run(lag_s: float, lagging: str, direction: str, seeds: int) -> str:
    taus, ses, before, after, secs = [], [], [], [], []
    for seed in range(seeds):
        ds, _ = t24_ramp_dataset(np.random.default_rng(seed), lag_s=lag_s, lagging=lagging)
        start = time.perf_counter()
        r = estimate_lag(ds.columns["t_s"], ds.h_nt, ds.temp_c, ds.ref_nt, direction=direction)
        secs.append(time.perf_counter() - start)
        taus.append(r.tau_s)
        ses.append(r.tau_se_s)
        before.append(r.updown_before_nt)
        after.append(r.updown_after_nt)
    taus_a = np.array(taus)
    spread = float(np.std(taus_a, ddof=1))
    return (
        f"{lagging:>7} lag {lag_s:5.0f} s, {direction:<12} ({ds.n} rows): tau {taus_a.mean():7.1f} s "
        f"(error {taus_a.mean() - lag_s:+5.1f} s), scatter {spread:4.2f} s vs stated {np.mean(ses):4.2f} s "
        f"(ratio {spread / np.mean(ses):4.2f}) | up/down {np.mean(before):6.1f} -> {np.mean(after):4.1f} nT "
        f"| {np.mean(secs) * 1e3:4.0f} ms per estimate"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    args = parser.parse_args()
    for lag_s in (300.0, 600.0, 900.0):
        print(run(lag_s, "element", "element_lags", args.seeds))
    print(run(600.0, "sensor", "auto", args.seeds))


if __name__ == "__main__":
    main()
