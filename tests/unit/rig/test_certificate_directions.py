"""The certificate's field directions: the largest angle from any direction to the nearest one the data
took (rig/report/certificate.py direction_reach_deg)."""

import numpy as np
import pytest

from rig.report.certificate import direction_reach_deg


def _fibonacci(n: int) -> np.ndarray:
    k = np.arange(n) + 0.5
    z = 1 - 2 * k / n
    phi = np.pi * (3 - np.sqrt(5)) * k + 0.7  # turned from the judged sphere's own directions
    return np.column_stack([np.sqrt(1 - z**2) * np.cos(phi), np.sqrt(1 - z**2) * np.sin(phi), z])


def test_the_farthest_direction_from_six_axes_is_a_cube_corner():
    axes = np.vstack([np.eye(3), -np.eye(3)]) * 50_000.0
    assert direction_reach_deg(axes) == pytest.approx(np.degrees(np.arccos(1 / np.sqrt(3))), abs=2.0)


def test_a_turntables_elevations_leave_the_poles_out_and_a_half_sphere_the_other_half():
    az, el = np.meshgrid(np.radians(np.arange(0, 360, 45)), np.radians([-60, 0, 60]))
    table = np.column_stack([(np.cos(el) * np.cos(az)).ravel(), (np.cos(el) * np.sin(az)).ravel(),
                             np.sin(el).ravel()])
    reach = direction_reach_deg(table * 48_000.0)
    assert 33.0 <= reach <= 36.5  # between the rows at el ~+-30 (35 deg); the poles are 30 from el +-60
    dense = _fibonacci(3000)
    assert direction_reach_deg(dense) < 5.0
    assert direction_reach_deg(dense[dense[:, 2] > 0.2]) == pytest.approx(90.0 + 11.5, abs=3.0)


def test_no_field_reaches_nothing():
    assert direction_reach_deg(np.zeros((4, 3))) == 180.0
