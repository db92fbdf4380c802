"""Synthetic data with known truth for every model (tests, benchmarks, simulators).

Every generator returns (Dataset, truth) where truth is a Calibration holding the true parameters, so
`truth.apply(ds.h_nt, ds.temp_c)` is the field the true calibration gives for the same noisy readings.
"""

from __future__ import annotations

import itertools

import numpy as np

from calib.calibration import Calibration
from calib.dataset import Dataset
from calib.equations import p12_matrix

DEFAULT_TEMPS_C = tuple(np.linspace(-30.0, 70.0, 6))


def coil_directions(n: int = 26, rng: np.random.Generator | None = None) -> np.ndarray:
    """Unit field directions: the 26 neighbours of a cube for n=26, else uniform random on the sphere."""
    if n == 26:
        d = np.array([p for p in itertools.product((-1, 0, 1), repeat=3) if any(p)], float)
    else:
        d = (rng or np.random.default_rng(0)).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _truth(model: str, params: dict, temp_ref_c: float | None = None) -> Calibration:
    zeros = {k: np.zeros_like(v) for k, v in params.items()}
    return Calibration(
        model=model,
        params=params,
        std_errors=zeros,
        temp_ref_c=temp_ref_c,
        source={"kind": "synthetic truth"},
    )


def random_t24_params(rng: np.random.Generator) -> dict:
    """T24 errors of the size an AMR datasheet allows (~2 % scale, ~1 % cross-axis, 150 ppm/degC)."""
    s = np.eye(3) + rng.normal(0, 0.01, (3, 3))
    s[np.diag_indices(3)] = 1 + rng.normal(0, 0.02, 3)
    return {
        "S": s,
        "K": rng.normal(0, 1.5e-4, (3, 3)),
        "b_nt": rng.normal(0, 400, 3),
        "kb_nt_per_c": rng.normal(0, 5, 3),
    }


def _add_outliers(h: np.ndarray, rng, fraction: float, size_nt: float) -> np.ndarray:
    """Replace a fraction of the readings by bumps of size_nt in random directions; returns the row mask."""
    mask = rng.random(h.shape[0]) < fraction
    bump = rng.normal(size=(int(mask.sum()), 3))
    h[mask] += size_nt * bump / np.linalg.norm(bump, axis=1, keepdims=True)
    return mask


def t24_dataset(
    rng: np.random.Generator,
    *,
    params: dict | None = None,
    temps_c=DEFAULT_TEMPS_C,
    directions: np.ndarray | None = None,
    samples_per_point: int = 20,
    field_nt: float = 50_000.0,
    noise_nt: float = 10.0,
    temp_jitter_c: float = 0.05,
    outlier_fraction: float = 0.0,
    outlier_nt: float = 5000.0,
):
    """Coil points (temperature step x field direction), noise on the raw readings (white, per axis)."""
    p = random_t24_params(rng) if params is None else params
    dirs = coil_directions() if directions is None else directions
    temps = np.repeat(np.asarray(temps_c, float), len(dirs) * samples_per_point)
    temps = temps + rng.normal(0, temp_jitter_c, temps.size) if temp_jitter_c else temps
    ref = field_nt * np.tile(np.repeat(dirs, samples_per_point, axis=0), (len(temps_c), 1))
    group = np.repeat(np.arange(len(temps_c)), len(dirs) * samples_per_point)
    h = np.empty_like(ref)
    for i, (t, b) in enumerate(zip(temps, ref, strict=True)):
        h[i] = np.linalg.solve(p["S"] + t * p["K"], b - p["b_nt"] - t * p["kb_nt_per_c"])
    h += rng.normal(0, noise_nt, h.shape)
    outliers = _add_outliers(h, rng, outlier_fraction, outlier_nt)
    ds = Dataset(
        h_nt=h,
        temp_c=temps,
        ref_nt=ref,
        group=group,
        columns={"is_outlier": outliers.astype(float)},
        source={"kind": "synthetic t24"},
    )
    return ds, _truth("t24", p)


def random_p12_params(rng: np.random.Generator) -> dict:
    return {
        "k": 1 + rng.normal(0, 0.02, 3),
        "angles_deg": rng.normal(0, 0.5, 3),
        "h0_nt": rng.normal(0, 400, 3),
    }


def p12_dataset(
    rng: np.random.Generator,
    *,
    params: dict | None = None,
    directions: np.ndarray | None = None,
    samples_per_point: int = 20,
    field_nt: float = 50_000.0,
    noise_nt: float = 10.0,
    outlier_fraction: float = 0.0,
    outlier_nt: float = 5000.0,
):
    """h = Q P B + h0 + n at constant temperature."""
    p = random_p12_params(rng) if params is None else params
    dirs = coil_directions() if directions is None else directions
    ref = field_nt * np.repeat(dirs, samples_per_point, axis=0)
    h = ref @ p12_matrix(p["k"], p["angles_deg"]).T + p["h0_nt"] + rng.normal(0, noise_nt, ref.shape)
    outliers = _add_outliers(h, rng, outlier_fraction, outlier_nt)
    ds = Dataset(
        h_nt=h,
        temp_c=None,
        ref_nt=ref,
        group=np.repeat(np.arange(len(dirs)), samples_per_point),
        columns={"is_outlier": outliers.astype(float)},
        source={"kind": "synthetic p12"},
    )
    return ds, _truth("p12", p)


def random_scalar_params(rng: np.random.Generator, temperature_terms: bool = False) -> dict:
    a = np.triu(np.eye(3) + rng.normal(0, 0.02, (3, 3)))
    p = {"A": a, "c_nt": rng.normal(0, 2000, 3)}
    if temperature_terms:
        p["KA_per_c"] = np.triu(rng.normal(0, 2e-4, (3, 3)))
        p["kc_nt_per_c"] = rng.normal(0, 10, 3)
    return p


def scalar_dataset(
    rng: np.random.Generator,
    *,
    params: dict | None = None,
    n: int = 2000,
    field_nt: float = 50_000.0,
    noise_nt: float = 10.0,
    temps_c=None,
    temp_ref_c: float = 25.0,
    outlier_fraction: float = 0.0,
    outlier_nt: float = 5000.0,
):
    """Random orientations in a constant-magnitude field; with temps_c, n samples at each temperature."""
    temperature_terms = temps_c is not None
    p = random_scalar_params(rng, temperature_terms) if params is None else params
    temps = np.repeat(np.asarray(temps_c, float), n) if temperature_terms else np.full(n, temp_ref_c)
    dirs = rng.normal(size=(temps.size, 3))
    ref = field_nt * dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    dt = (temps - temp_ref_c)[:, None]
    h = np.empty_like(ref)
    for i in range(len(ref)):
        a = p["A"] + (dt[i, 0] * p["KA_per_c"] if temperature_terms else 0)
        c = p["c_nt"] + (dt[i, 0] * p["kc_nt_per_c"] if temperature_terms else 0)
        h[i] = np.linalg.solve(a, ref[i]) + c
    h += rng.normal(0, noise_nt, h.shape)
    outliers = _add_outliers(h, rng, outlier_fraction, outlier_nt)
    ds = Dataset(
        h_nt=h,
        temp_c=temps if temperature_terms else None,
        ref_nt=None,
        ref_norm_nt=np.full(len(ref), field_nt),
        columns={"is_outlier": outliers.astype(float)},
        source={"kind": "synthetic scalar"},
    )
    return ds, _truth("scalar", p, temp_ref_c if temperature_terms else None)


def ramp_profile_c(
    t_s: np.ndarray, temps_c=(-20.0, 60.0), rate_c_per_min: float = 1.0, dwell_s: float = 1800.0,
    cycles: int = 1,
) -> np.ndarray:
    """Chamber air: dwell at temps_c[0], ramp to temps_c[1], dwell, ramp back, dwell; `cycles` times."""
    lo, hi = temps_c
    ramp_s = abs(hi - lo) / rate_c_per_min * 60.0
    knots_t, knots_c = [0.0], [lo]
    for _ in range(cycles):
        for target in (hi, lo):
            knots_t += [knots_t[-1] + dwell_s, knots_t[-1] + dwell_s + ramp_s]
            knots_c += [knots_c[-1], target]
    knots_t.append(knots_t[-1] + dwell_s)
    knots_c.append(lo)
    return np.interp(t_s, knots_t, knots_c)


def first_order_lag(t_s: np.ndarray, x: np.ndarray, lag_s: float, substep_s: float = 1.0) -> np.ndarray:
    """y following x with dy/dt = (x - y)/lag_s from y = x at t_s[0]: integrated on sub-steps with x held at
    each sub-step's midpoint (the world simulator's way, not calib.thermal.lag's closed form)."""
    if lag_s <= 0:
        return np.asarray(x, float).copy()
    fine = np.arange(t_s[0], t_s[-1] + substep_s, substep_s)
    x_fine = np.interp(fine, t_s, x)
    mids = np.interp(fine[:-1] + 0.5 * substep_s, t_s, x)
    y = np.empty_like(fine)
    y[0] = x_fine[0]
    a = np.exp(-substep_s / lag_s)
    for k, mid in enumerate(mids):
        y[k + 1] = mid + (y[k] - mid) * a
    return np.interp(t_s, fine, y)


def t24_ramp_dataset(
    rng: np.random.Generator,
    *,
    params: dict | None = None,
    lag_s: float = 600.0,
    lagging: str = "element",
    temps_c=(-20.0, 60.0),
    rate_c_per_min: float = 1.0,
    dwell_s: float = 1800.0,
    cycles: int = 1,
    sample_s: float = 10.0,
    directions: np.ndarray | None = None,
    field_nt: float = 50_000.0,
    noise_nt: float = 10.0,
    temp_noise_c: float = 0.01,
):
    """A continuous-ramp time series: the coils step through `directions` one per sample while the air
    follows ramp_profile_c. lagging="element": the recorded temperature is the air and the element lags it
    by lag_s (the simulator's DUT); "sensor": the element is at the air and the recorded sensor lags it.
    The Dataset's columns hold t_s and the true temp_element_c; temp_c is the recorded temperature."""
    if lagging not in ("element", "sensor"):
        raise ValueError(f"lagging {lagging!r}: element or sensor")
    p = random_t24_params(rng) if params is None else params
    dirs = coil_directions() if directions is None else directions
    duration_s = cycles * 2 * (abs(temps_c[1] - temps_c[0]) / rate_c_per_min * 60.0 + dwell_s) + dwell_s
    t = np.arange(0.0, duration_s, sample_s)
    air = ramp_profile_c(t, temps_c, rate_c_per_min, dwell_s, cycles)
    lagged = first_order_lag(t, air, lag_s)
    element, recorded = (lagged, air) if lagging == "element" else (air, lagged)
    ref = field_nt * dirs[np.arange(t.size) % len(dirs)]
    m = p["S"][None] + element[:, None, None] * p["K"][None]
    rhs = ref - p["b_nt"] - element[:, None] * p["kb_nt_per_c"]
    h = np.linalg.solve(m, rhs[..., None])[..., 0] + rng.normal(0, noise_nt, ref.shape)
    ds = Dataset(
        h_nt=h,
        temp_c=recorded + rng.normal(0, temp_noise_c, t.size),
        ref_nt=ref,
        columns={"t_s": t, "temp_element_c": element},
        source={"kind": f"synthetic t24 ramp, {lagging} lag {lag_s} s"},
    )
    return ds, _truth("t24", p)
