"""The model check of T24's linearity in temperature (calib/checks/linearity.py)."""

from __future__ import annotations

import numpy as np
import pytest

from calib.checks.linearity import chi2_sf_even, linearity
from calib.synthetic import coil_directions, random_t24_params


def campaign(temps_c, curvature_nt_per_c2: float = 0.0, seed: int = 3):
    """Raw readings of a T24 sensor at every temperature x 26 directions x 10 samples, with an extra offset
    curvature_nt_per_c2 (tau - 20)^2 on the x axis that T24 cannot follow."""
    rng = np.random.default_rng(seed)
    p = random_t24_params(rng)
    ref = 50_000 * np.tile(np.repeat(coil_directions(26), 10, axis=0), (len(temps_c), 1))
    temp = np.repeat(temps_c, 260)
    h = np.array([np.linalg.solve(p["S"] + t * p["K"], b - p["b_nt"] - t * p["kb_nt_per_c"])
                  for b, t in zip(ref, temp, strict=True)]) + rng.normal(0, 20, ref.shape)
    ref = ref + np.outer(curvature_nt_per_c2 * (temp - 20.0) ** 2, [1.0, 0.0, 0.0])
    return h, temp, ref


def test_a_t24_sensor_passes_and_a_curved_one_is_caught_with_its_size():
    clean = linearity(*campaign([-30.0, -5.0, 20.0, 45.0, 70.0]))
    assert clean["testable"] and clean["holds"] and clean["p"] > 1e-3
    curved = linearity(*campaign([-30.0, -5.0, 20.0, 45.0, 70.0], curvature_nt_per_c2=0.004))
    assert curved["holds"] is False and curved["p"] < 1e-6 and "does not hold" in curved["message"]
    # 10 nT at the ends, seen through the noise of a fitted term (a few nT here)
    assert 0.004 * 50**2 < curved["quadratic_nt"] < 2 * 0.004 * 50**2


def test_two_temperatures_cannot_show_a_curve():
    check = linearity(*campaign([-30.0, 70.0], curvature_nt_per_c2=0.004))
    assert not check["testable"] and check["holds"] is None and "interior" in check["message"]


def test_chi_square_tail_matches_known_values():
    assert chi2_sf_even(0.0, 12) == 1.0
    assert chi2_sf_even(26.217, 12) == pytest.approx(0.01, rel=1e-3)
    assert chi2_sf_even(9.488, 4) == pytest.approx(0.05, rel=1e-3)
