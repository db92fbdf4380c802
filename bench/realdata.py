"""Real recordings (shared/realdata, README there): scalar fit on the first half of each, |B| spread
(std/mean) on the held-out second half. Reference on the full-sphere HMC5883L: magcc 0.1.1 reaches 0.66 %
out of sample (0.46 % in sample on the whole recording). Skips a recording whose file is absent.

Each is fitted with orientation balancing off (the plain least-squares fit, the same estimator as
magcc's LM fit), with the default (the variant chosen by validation inside the training rows,
calib/models/scalar_choice.py) and robust.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the rig command does (rig/cli/__init__.py)

import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

import calib  # noqa: E402
from calib.io import csvio  # noqa: E402

# shared/ sits beside the repository (as in CI); MAGRIG_REALDATA points elsewhere
BESIDE_REPO = Path(__file__).resolve().parents[1].parent / "shared" / "realdata"
REAL = Path(os.environ.get("MAGRIG_REALDATA", BESIDE_REPO))
HMC_COLUMNS = {"hx": "mx_gauss", "hy": "my_gauss", "hz": "mz_gauss"}
RECORDINGS = {
    "HMC5883L full sphere": ("hmc5883l_fullsphere_sunsided/hmc5883l_mag.csv", {"raw_unit": "gauss"}),
    "HMC5883L tilt sphere": ("hmc5883l_tiltsphere_sunsided/hmc5883l_mag.csv", {"raw_unit": "gauss"}),
    "GyroLib (temperature column)": (
        "gyrolib_rahrs/calibrationGyroLib.csv",
        {"raw_unit": "counts", "counts_per_unit": 1.0},
    ),
}
GYROLIB_COLUMNS = {"hx": "Mx", "hy": "My", "hz": "Mz", "temp": "temperature"}


def spread_pct(field_nt: np.ndarray) -> float:
    norm = np.linalg.norm(field_nt, axis=1)
    return float(100 * norm.std() / norm.mean())


def held_out(name: str, path: Path, read_options: dict) -> None:
    columns = GYROLIB_COLUMNS if "gyrolib" in str(path) else HMC_COLUMNS
    ds = csvio.read_csv(path, columns=columns, **read_options)
    half = len(ds) // 2
    first, second = ds.subset(slice(0, half)), ds.subset(slice(half, None))
    print(f"{name}, {len(ds)} samples; raw |B| spread {spread_pct(second.h_nt):.2f} % (held-out half)")
    variants = {
        "balancing off": {"balance_orientations": False},
        "default": {},
        "robust": {"robust": True},
    }
    temperature_choices = (None, False) if ds.temp_c is not None else (None,)
    for temperature_terms in temperature_choices:
        for label, options in variants.items():
            cal = calib.fit(first, "scalar", temperature_terms=temperature_terms, **options)
            stats = cal.stats
            what = f"{label}{', temperature terms' if stats['temperature_terms'] else ''}"
            share = stats.get("coverage_effective_share")
            print(
                f"  {what:36s} in-sample {stats['norm_spread_pct']:.3f} %   out-of-sample "
                f"{spread_pct(cal.apply(second.h_nt, second.temp_c)):.3f} %   "
                f"(balanced: {stats['balance_orientations']}"
                + ("" if share is None else f", coverage share {share:.2f}")
                + ("" if "validation" not in stats else f", chosen by validation: {_chosen(stats)}")
                + ")"
            )


def _chosen(stats: dict) -> str:
    v = stats["validation"]
    means = ", ".join(f"{name} {m:.3f}" for name, m in v.get("mean_pct", {}).items())
    return f"{v['chosen']} (fold means {means} %)"


def default_fit_time_s(path: Path, repeats: int = 5) -> tuple[float, int]:
    """Median wall time of calib.fit(..., "scalar") with every option left to validation."""
    ds = csvio.read_csv(path, raw_unit="gauss", columns=HMC_COLUMNS)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        calib.fit(ds, "scalar")
        times.append(time.perf_counter() - start)
    return float(np.median(times)), len(ds)


def split_masks(n: int, seed: int = 0) -> dict[str, np.ndarray]:
    """Training rows of each split (the rest is held out): contiguous halves both ways, interleaved
    blocks both ways, random half of 16 contiguous blocks, two thirds."""
    idx = np.arange(n)
    masks = {"first half": idx < n // 2, "second half": idx >= n // 2}
    for blocks in (4, 10, 20):
        block = idx * blocks // n
        masks[f"even of {blocks} blocks"] = block % 2 == 0
        masks[f"odd of {blocks} blocks"] = block % 2 == 1
    rng = np.random.default_rng(seed)
    for k in range(3):
        masks[f"random 8 of 16 blocks #{k}"] = np.isin(idx * 16 // n, rng.permutation(16)[:8])
    for third in range(3):
        masks[f"all but third {third + 1}"] = idx * 3 // n != third
    return masks


def against_magcc(path: Path) -> None:
    """Held-out |B| spread of our scalar fits over magcc's LM fit's, on every split of split_masks.

    Two ceilings close the table: one fixed ellipsoid fitted to every row of the recording (training
    and held-out), and one fitted to the held-out rows themselves. Neither is a calibration anyone could
    make from the training rows; they bound what such a calibration can reach on each split.
    """
    try:
        from magcc.magcc import calibrate_lm
    except ImportError:
        print("splits against magcc skipped: pip install magcc==0.1.1 to measure them")
        return
    ds = csvio.read_csv(path, raw_unit="gauss", columns=HMC_COLUMNS)
    every_row = calib.fit(ds, "scalar", balance_orientations=False)
    print("full sphere, held-out |B| spread over magcc 0.1.1 calibrate_lm's (train -> the rest):")
    print(f"  {'training rows':26s} {'magcc %':>8s} {'plain':>7s} {'default':>8s} {'balanced':>9s}"
          f" {'ceiling: all rows':>18s} {'held-out rows':>14s}   default's choice")
    ratios = []
    for name, train in split_masks(len(ds)).items():
        fit_on, held = ds.subset(train), ds.subset(~train)
        hard, soft, _, _ = calibrate_lm(fit_on.h_nt, 50_000.0)
        ref = spread_pct((held.h_nt - hard) @ soft.T)
        fits = [calib.fit(fit_on, "scalar", balance_orientations=b) for b in (False, None, True)]
        ours = [spread_pct(cal.apply(held.h_nt)) / ref for cal in fits]
        ceilings = [
            spread_pct(every_row.apply(held.h_nt)) / ref,
            spread_pct(calib.fit(held, "scalar", balance_orientations=False).apply(held.h_nt)) / ref,
        ]
        ratios.append(ours + ceilings)
        print(f"  {name:26s} {ref:8.3f} {ours[0]:7.3f} {ours[1]:8.3f} {ours[2]:9.3f}"
              f" {ceilings[0]:18.3f} {ceilings[1]:14.3f}   {fits[1].stats['validation']['chosen']}")
    worst = np.max(ratios, axis=0)
    print(f"  {'worst ratio':26s} {'':8s} {worst[0]:7.3f} {worst[1]:8.3f} {worst[2]:9.3f}"
          f" {worst[3]:18.3f} {worst[4]:14.3f}")


def main() -> None:
    for name, (relative, read_options) in RECORDINGS.items():
        path = REAL / relative
        if not path.exists():
            print(f"skipped {name}: {path} not present")
            continue
        held_out(name, path, read_options)
    full = REAL / RECORDINGS["HMC5883L full sphere"][0]
    if full.exists():
        ds = csvio.read_csv(full, raw_unit="gauss", columns=HMC_COLUMNS)
        cal = calib.fit(ds, "scalar", balance_orientations=False)
        print(
            f"full sphere, whole recording, balancing off, in-sample {cal.stats['norm_spread_pct']:.3f} % "
            "(magcc 0.1.1: 0.46 %)"
        )
    print("magcc 0.1.1 on the full sphere held-out half: 0.66 %")
    if full.exists():
        seconds, rows = default_fit_time_s(full)
        print(f"full sphere, default scalar fit (with its validation) of {rows} rows: {seconds:.3f} s "
              "(median of 5)")
        against_magcc(full)


if __name__ == "__main__":
    main()
