"""The field directions a calibration's data took (calib/stats/directions.py): how far every direction is from
them, and how far apart they are."""

import numpy as np
import pytest

from calib.stats.directions import nearest_deg, reach_deg, spacing_deg, taken_directions


def _fibonacci(n: int) -> np.ndarray:
    k = np.arange(n) + 0.5
    z = 1 - 2 * k / n
    phi = np.pi * (3 - np.sqrt(5)) * k + 0.7  # turned from the judged sphere's own directions
    return np.column_stack([np.sqrt(1 - z**2) * np.cos(phi), np.sqrt(1 - z**2) * np.sin(phi), z])


def _reach(field_nt) -> float:
    return reach_deg(taken_directions(field_nt))


def test_the_farthest_direction_from_six_axes_is_a_cube_corner():
    axes = np.vstack([np.eye(3), -np.eye(3)]) * 50_000.0
    assert _reach(axes) == pytest.approx(np.degrees(np.arccos(1 / np.sqrt(3))), abs=2.0)


def test_a_turntables_elevations_leave_the_poles_out_and_a_half_sphere_the_other_half():
    az, el = np.meshgrid(np.radians(np.arange(0, 360, 45)), np.radians([-60, 0, 60]))
    table = np.column_stack([(np.cos(el) * np.cos(az)).ravel(), (np.cos(el) * np.sin(az)).ravel(),
                             np.sin(el).ravel()])
    reach = _reach(table * 48_000.0)
    assert 33.0 <= reach <= 36.5  # between the rows at el ~+-30 (35 deg); the poles are 30 from el +-60
    dense = _fibonacci(900)  # about 7 deg apart
    assert _reach(dense) < 6.0
    assert _reach(_fibonacci(3000)) < 10.0  # recorded at a coarser rounding (MAX_DIRECTIONS)
    assert _reach(dense[dense[:, 2] > 0.2]) == pytest.approx(90.0 + 11.5, abs=3.0)


def test_no_field_reaches_nothing():
    assert _reach(np.zeros((4, 3))) == 180.0


def test_a_field_among_the_directions_taken_is_near_one_and_one_below_them_is_not():
    az, el = np.meshgrid(np.radians(np.arange(0, 360, 45)), np.radians([-60, 0, 60]))
    grid = np.column_stack([(np.cos(el) * np.cos(az)).ravel(), (np.cos(el) * np.sin(az)).ravel(),
                            np.sin(el).ravel()])
    upper = taken_directions(grid[grid[:, 2] > -0.5] * 50_000.0)  # el -60 left out
    assert len(upper) == 16 and spacing_deg(upper) == pytest.approx(45.0, abs=0.5)  # along el 0
    angles = nearest_deg(upper, [[0.0, 0.0, 30_000.0], [1.0, 1.0, 0.2], [0.0, 0.0, -20_000.0], [0, 0, 0]])
    assert angles[0] == pytest.approx(30.0, abs=0.5)  # the pole, from el 60
    assert angles[1] < 45.0  # between azimuths on the equator
    assert angles[2] == pytest.approx(90.0, abs=0.5)  # straight down: a quarter turn from el 0
    assert angles[3] == 0.0
    # each pose taken again at another temperature, a degree or two off: the spacing is the poses'
    turned = grid + np.random.default_rng(2).normal(0, 0.02, grid.shape)
    again = taken_directions(np.vstack([grid, turned])[np.vstack([grid, turned])[:, 2] > -0.5])
    assert len(again) > 16 and spacing_deg(again) == pytest.approx(45.0, abs=3.0)
