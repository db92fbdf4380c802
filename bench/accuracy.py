"""Accuracy against the ideal: the excess error of each fit over an efficient estimator's, on synthetic data.

excess = RMS over fresh validation readings of (our calibrated field - the true calibration applied to the
same noisy readings), divided by the RMS an efficient estimator would have there (sigma^2 G^-1 propagated
to those points), pooled over 20 seeds (P12: 100). 1.00 is the limit. Also: digits kept by our solver
and by the paper's closed form against a 60-digit solution.
"""

from __future__ import annotations

import numpy as np

import calib
from calib import synthetic
from calib.models import t24_paper
from calib.models.gram import GramAccumulator
from calib.models.registry import p12_matrix

SEEDS = range(20)
P12_SEEDS = range(100)  # P12 fits are cheap; 20 seeds leave the ratio uncertain by ~3 %
NOISE_NT = 10.0


def _t24_design(h, temp, ref_c):
    t = (temp - ref_c)[:, None]
    return np.column_stack([np.ones(len(h)), t[:, 0], h, t * h])


def t24_excess(outlier_fraction: float = 0.0, robust: bool = False) -> float:
    err2 = pred2 = 0.0
    for seed in SEEDS:
        rng = np.random.default_rng(seed)
        ds, truth = synthetic.t24_dataset(rng, noise_nt=NOISE_NT, outlier_fraction=outlier_fraction)
        cal = calib.fit(ds, "t24", robust=robust, temp_ref_c=20.0)
        clean = ~ds.columns["is_outlier"].astype(bool)
        # fresh validation points: random directions and temperatures within the calibrated range
        val, _ = synthetic.t24_dataset(
            rng,
            params=truth.params,
            temps_c=rng.uniform(-30, 70, 40),
            directions=synthetic.coil_directions(30, rng),
            samples_per_point=1,
            noise_nt=NOISE_NT,
        )
        err = cal.apply(val.h_nt, val.temp_c) - truth.apply(val.h_nt, val.temp_c)
        x_fit = _t24_design(ds.h_nt[clean], ds.temp_c[clean], 20.0)
        x_val = _t24_design(val.h_nt, val.temp_c, 20.0)
        leverage = np.einsum("ij,jk,ik->i", x_val, np.linalg.inv(x_fit.T @ x_fit), x_val)
        # noise in the field domain: (S + T K) n, per axis
        m = truth.params["S"] + val.temp_c[:, None, None] * truth.params["K"]
        sigma2 = NOISE_NT**2 * np.sum(m**2, axis=2)  # (N,3)
        err2 += np.sum(err**2)
        pred2 += np.sum(sigma2 * leverage[:, None])
    return float(np.sqrt(err2 / pred2))


def p12_excess(outlier_fraction: float = 0.0, robust: bool = False) -> float:
    err2 = pred2 = 0.0
    for seed in P12_SEEDS:
        rng = np.random.default_rng(1000 + seed)
        ds, truth = synthetic.p12_dataset(rng, noise_nt=NOISE_NT, outlier_fraction=outlier_fraction)
        cal = calib.fit(ds, "p12", robust=robust)
        clean = ~ds.columns["is_outlier"].astype(bool)
        val, _ = synthetic.p12_dataset(
            rng,
            params=truth.params,
            directions=synthetic.coil_directions(300, rng),
            samples_per_point=1,
            noise_nt=NOISE_NT,
        )
        err = cal.apply(val.h_nt) - truth.apply(val.h_nt)
        m_inv = np.linalg.inv(p12_matrix(truth.params["k"], truth.params["angles_deg"]))
        b_val = truth.apply(val.h_nt)
        var_h = np.zeros((len(val), 3))
        for i in range(3):
            x_fit = np.column_stack([ds.ref_nt[clean, : i + 1], np.ones(int(clean.sum()))])
            x_val = np.column_stack([b_val[:, : i + 1], np.ones(len(val))])
            var_h[:, i] = NOISE_NT**2 * np.einsum("ij,jk,ik->i", x_val, np.linalg.inv(x_fit.T @ x_fit), x_val)
        err2 += np.sum(err**2)
        pred2 += np.sum(var_h @ (m_inv**2).T)
    return float(np.sqrt(err2 / pred2))


def digits_cases() -> list[tuple[str, float, float]]:
    rows = []
    for label, temps in (
        ("tau -40..+85 degC", np.linspace(-40, 85, 6)),
        ("tau 25 +- 0.5 degC", np.linspace(24.5, 25.5, 6)),
    ):
        ds, _ = synthetic.t24_dataset(
            np.random.default_rng(0),
            temps_c=temps,
            field_nt=100_000.0,
            samples_per_point=2,
            temp_jitter_c=0.0,
            noise_nt=NOISE_NT,
        )
        exact = t24_paper.exact_solution(ds.h_nt, ds.temp_c, ds.ref_nt)
        acc = GramAccumulator(round(float(np.mean(temps)), 1))
        acc.add(ds.h_nt, ds.temp_c, ds.ref_nt)
        ours = t24_paper.digits_kept(acc.solve().params, exact)
        paper = t24_paper.digits_kept(t24_paper.paper_solution(ds.h_nt, ds.temp_c, ds.ref_nt), exact)
        rows.append((label, ours, paper))
    return rows


def main() -> None:
    print("accuracy: excess error over an efficient estimator (1.00 = the limit), 20 seeds")
    print("  T24, 6 steps -30..+70 degC x 26 directions x 20 samples, 10 nT noise:")
    print(f"    least squares                          excess {t24_excess():.3f}   (target <= 1.03)")
    print(
        f"    1 % outliers of 5000 nT, robust        excess {t24_excess(0.01, True):.3f}   (target <= 1.10)"
    )
    print(f"    1 % outliers of 5000 nT, plain LS      excess {t24_excess(0.01, False):.1f}")
    print("  P12, 26 directions x 20 samples, 10 nT noise (100 seeds):")
    print(f"    least squares                          excess {p12_excess():.3f}")
    print(f"    1 % outliers of 5000 nT, robust        excess {p12_excess(0.01, True):.3f}")
    print(f"    1 % outliers of 5000 nT, plain LS      excess {p12_excess(0.01, False):.1f}")
    print("  digits kept against a 60-digit solution (|B| = 100000 nT):")
    for label, ours, paper in digits_cases():
        print(f"    {label:22s} ours {ours:5.1f}   paper closed form {paper:5.1f}")


if __name__ == "__main__":
    main()
