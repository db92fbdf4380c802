"""The lab's field beyond a uniform, steady ambient (drivers/sim/world/labfield.py): its gradient at each
sensor's true position (`sim.ambient_gradient_nt_per_m`) and its Poisson-timed steps (`sim.ambient_steps`)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.sim.world.labfield import AmbientSteps
from tests.unit.drivers.sim.benches import IDEAL, world_of

GRADIENT = [[40.0, -5.0, 0.0], [3.0, 12.0, 7.0], [0.0, -9.0, -52.0]]  # nT/m, dB_i/dx_j


def test_two_duts_see_the_gradient_between_their_true_positions(tmp_path):
    duts = {"a": {"position_mm": [60, -20, 10], "sim": {"truth": IDEAL, "noise_nt": 0,
                                                        "position_error_mm": [1.5, 0, -2]}},
            "b": {"position_mm": [-45, 30, 0], "sim": {"truth": IDEAL, "noise_nt": 0}}}
    ambient = [16_000.0, -300.0, 43_000.0]
    sim = {"ambient_nt": ambient, "ambient_gradient_nt_per_m": GRADIENT}
    world, _ = world_of(tmp_path, sim=sim, duts=duts)
    true_a, true_b = np.array([61.5, -20.0, 8.0]) / 1000, np.array([-45.0, 30.0, 0.0]) / 1000
    np.testing.assert_allclose(world.lab_field_nt("a") - world.lab_field_nt("b"),
                               np.asarray(GRADIENT) @ (true_a - true_b), atol=1e-9)
    np.testing.assert_allclose(world.lab_field_nt("a"), ambient + np.asarray(GRADIENT) @ true_a, atol=1e-9)
    np.testing.assert_allclose(world.lab_field_nt(), ambient)  # at the centre: the ambient itself


def test_steps_come_at_poisson_times_with_their_stated_size():
    mean_h, size_nt, hours = 0.5, 20.0, 4000.0
    steps = AmbientSteps(np.random.default_rng(2), 0.0, mean_interval_h=mean_h, size_nt=size_nt)
    total = steps.offset_nt(hours * 3600)  # drawn lazily, up to the time asked
    expected = hours / mean_h  # 8000 steps, standard deviation 89
    assert len(steps.times_s) == pytest.approx(expected, abs=5 * math.sqrt(expected))
    assert steps.times_s[-1] <= hours * 3600 < steps.next_s
    gaps_h = np.diff(steps.times_s) / 3600
    assert np.mean(gaps_h) == pytest.approx(mean_h, rel=5 / math.sqrt(gaps_h.size))  # exponential: sd = mean
    assert np.std(gaps_h) == pytest.approx(mean_h, rel=0.1)
    # isotropic normal steps of RMS size_nt: |v|^2 / size^2 ~ chi2(3) / 3, whose sd is sqrt(2/3)
    squares = np.sum(np.square(steps.steps_nt), axis=1) / size_nt**2
    assert np.mean(squares) == pytest.approx(1.0, abs=5 * math.sqrt(2 / 3 / squares.size))
    np.testing.assert_allclose(total, np.sum(steps.steps_nt, axis=0), atol=1e-9)


def test_steps_reach_the_field_and_fall_where_the_seed_says_whenever_asked(tmp_path):
    sim = {"ambient_nt": [15_000, 500, 42_000], "ambient_steps": {"mean_interval_h": 2.0, "size_nt": 50.0}}
    often, clock = world_of(tmp_path, sim=sim)
    fields = []
    for _ in range(48 * 6):  # every ten minutes for two days
        clock.sleep(600.0)
        fields.append(often.lab_field_nt())
    changes = np.count_nonzero(np.any(np.diff(fields, axis=0) != 0, axis=1))
    assert 5 <= changes <= 50  # 24 expected: Poisson, 5 sigma either side
    once, clock2 = world_of(tmp_path, sim=sim)
    clock2.sleep(48 * 3600.0)  # one jump of two days
    assert np.array_equal(once.lab_field_nt(), fields[-1])


def test_a_dut_on_a_turntable_turns_with_it_through_the_gradient(tmp_path):
    """On a table its position is on the table: turned to (az, el) it sits at R r in the lab, sees
    site + G R r there, and reads that in the table's frame, R^T (site + G R r)."""
    site = np.array([19_148.0, 894.0, 45_587.0])
    duts = {"a": {"position_mm": [60, 0, 10], "sim": {"truth": IDEAL, "noise_nt": 0}}}
    table = {"kind": "turntable", "transport": {"kind": "sim"}, "rate_deg_s": 30,
             "site_field": {"vector_nt": site.tolist()}}
    sim = {"site_field_nt": site.tolist(), "ambient_gradient_nt_per_m": GRADIENT}
    world, clock = world_of(tmp_path, sim=sim, duts=duts, field_source=table)
    r, g = np.array([60.0, 0.0, 10.0]) / 1000, np.asarray(GRADIENT)
    for az, el in ((0.0, 0.0), (90.0, 0.0), (200.0, -60.0)):
        world.set_turntable_target(az, el)
        clock.sleep(30.0)
        turned = world.turntable_axes.rotation(az, el)
        np.testing.assert_allclose(world.lab_field_nt("a"), turned.T @ (site + g @ turned @ r), atol=1e-9)
    assert not np.allclose(world.lab_field_nt("a"), turned.T @ (site + g @ r), atol=1.0)  # not where it was
