"""The coil field off the centre: the rig's closed forms against textbook values, against a brute-force
Biot-Savart sum, and against the simulator's own numerical integration (drivers/sim/world/coilfield.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.sim.world.coilfield import CoilGeometry as SimGeometry
from drivers.sim.world.coilfield import coil_matrix_at as sim_matrix_at
from rig.fieldsources.coils import geometry as cg

MU0 = 4e-7 * math.pi


def test_square_loop_on_its_axis_matches_the_textbook_formula():
    a, z = 0.4, 0.1  # hardware-notes 7.1: B_z = mu0 I a^2 / (2 pi (z^2 + a^2/4) sqrt(z^2 + a^2/2))
    b = cg._square_loop_field(2, 0.0, a, np.array([[0.0, 0.0, z]]))[0]
    expected = MU0 * a**2 / (2 * math.pi * (z**2 + a**2 / 4) * math.sqrt(z**2 + a**2 / 2))
    assert b[2] == pytest.approx(expected, rel=1e-12) and abs(b[0]) < 1e-20 and abs(b[1]) < 1e-20


def test_circular_helmholtz_pair_centre_field():
    radius = 0.2  # (4/5)^(3/2) mu0 N I / R at separation R
    b = cg.pair_field("circular", 0, 2 * radius, radius, np.zeros((1, 3)))[0]
    assert b[0] == pytest.approx((4 / 5) ** 1.5 * MU0 / radius, rel=1e-12)


def _brute_loop(shape, axis, offset, size, point, n=20_000):
    u, v = (axis + 1) % 3, (axis + 2) % 3
    s = (np.arange(n) + 0.5) / n
    if shape == "circular":
        th = 2 * np.pi * s
        pts = np.zeros((n, 3))
        pts[:, axis], pts[:, u], pts[:, v] = offset, size / 2 * np.cos(th), size / 2 * np.sin(th)
        dl = np.zeros((n, 3))
        dl[:, u], dl[:, v] = -size / 2 * np.sin(th) * 2 * np.pi / n, size / 2 * np.cos(th) * 2 * np.pi / n
    else:
        h = size / 2
        corners = [(h, -h), (h, h), (-h, h), (-h, -h)]
        pts, dl = [], []
        for k in range(4):
            a, b = np.zeros(3), np.zeros(3)
            a[axis] = b[axis] = offset
            (a[u], a[v]), (b[u], b[v]) = corners[k], corners[(k + 1) % 4]
            pts.append(a + np.outer(s, b - a))
            dl.append(np.tile((b - a) / n, (n, 1)))
        pts, dl = np.vstack(pts), np.vstack(dl)
    r = point - pts
    return MU0 / (4 * np.pi) * np.sum(np.cross(dl, r) / np.linalg.norm(r, axis=1)[:, None] ** 3, axis=0)


@pytest.mark.parametrize("shape", ["square", "circular"])
def test_off_axis_field_matches_a_brute_force_sum(shape):
    point = np.array([0.05, -0.07, 0.03])
    loop = cg.LOOPS[shape]
    for axis in range(3):
        ours = loop(axis, 0.1, 0.4, point[None])[0]
        assert np.allclose(ours, _brute_loop(shape, axis, 0.1, 0.4, point), rtol=1e-6, atol=1e-14)


@pytest.mark.parametrize("shape,spacing", [("square", 0.5445 * 0.4), ("circular", 0.2)])
def test_the_rig_and_the_simulator_agree_on_a_tilted_scaled_coil_set(shape, spacing):
    """Independent numerics (closed forms / quadrature) of the same physical model."""
    size, space = (0.40, 0.41, 0.39), (spacing, spacing * 1.02, spacing * 0.98)
    true = np.diag([50_500.0, 49_600.0, 50_300.0])
    tilt = math.radians(0.3)
    true[:, 0] = 50_500.0 * np.array([math.cos(tilt), math.sin(tilt), 0.001])
    true[:, 2] = 50_300.0 * np.array([0.0, math.sin(tilt), math.cos(tilt)])
    for position in ([0.07, -0.05, 0.03], [0.0, 0.0, 0.0], [-0.04, 0.06, -0.02]):
        ours = cg.coil_matrix_at(true, shape, size, space, np.array([position]))[0]
        theirs = sim_matrix_at(true, SimGeometry(shape, size, space), position)
        assert np.abs(ours - theirs).max() < 1e-6  # nT/A, out of 50 000
    assert np.allclose(cg.coil_matrix_at(true, shape, size, space, np.zeros((1, 3)))[0], true, atol=1e-8)


def test_nonuniformity_grows_with_distance_and_is_zero_at_the_centre():
    size, spacing = (0.4,) * 3, (0.5445 * 0.4,) * 3
    assert cg.nonuniformity("square", size, spacing, np.zeros(3)) < 1e-12
    values = [cg.nonuniformity("square", size, spacing, [r, 0, 0]) for r in (0.02, 0.04, 0.07)]
    assert values[0] < values[1] < values[2]
    assert 1e-3 < values[2] < 3e-2  # 70 mm off the centre of a 0.4 m set: ~1 %


def test_inside_the_coil_set():
    size, spacing = (0.4,) * 3, (0.22,) * 3
    assert cg.inside("square", size, spacing, [0.07, 0.05, -0.05])
    assert not cg.inside("square", size, spacing, [0.12, 0, 0])  # beyond the x pair's planes
    assert cg.inside("square", size, spacing, [0.09, 0.09, 0.09])
    assert not cg.inside("circular", (0.2,) * 3, (0.2,) * 3, [0.09, 0.09, 0.0])  # outside the circles
