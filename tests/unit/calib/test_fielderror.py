"""A calibration file's uncertainty at any reading (calib/uncertainty/fielderror.py): the parameters'
covariance and the model error, the file's exact round trip, old files, and a malformed covariance refused."""

from __future__ import annotations

import numpy as np
import pytest

import calib
from calib import synthetic
from calib.calibration import Calibration
from calib.errors import DataError
from calib.io import calfile
from calib.uncertainty.budgeting import budget
from calib.uncertainty.fielderror import expanded_at, expanded_norm_at, field_covariance, parameter_covariance
from calib.uncertainty.propagation import matrix_source, offset_source


def _calibrated(seed: int = 1):
    ds, _ = synthetic.t24_dataset(np.random.default_rng(seed), temps_c=(-20.0, 20.0, 60.0),
                                  samples_per_point=2)
    cal = calib.fit(ds, "t24")
    currents = ds.ref_nt / 10_000.0
    sources = [matrix_source("coil matrix", currents, np.eye(9).reshape(9, 3, 3), np.eye(9) * 0.5**2),
               offset_source("ambient", len(ds), np.eye(3) * 3.0**2)]
    fields = 50_000.0 * synthetic.coil_directions()
    grid = (np.repeat(fields, 2, axis=0), np.tile([-20.0, 60.0], len(fields)))
    b = budget(ds, cal, sources, grid, rng=np.random.default_rng(seed))
    cal.uncertainty = {**b.as_dict(), "model_error_nt": [4.0, 5.0, 6.0]}
    return cal, b


def test_the_field_uncertainty_at_the_grid_is_the_budgets_plus_the_model_error(tmp_path):
    cal, b = _calibrated()
    h = b.linear.grid_h_nt
    cov = field_covariance(cal, h, b.linear.grid_temp_c)
    np.testing.assert_allclose(cov - np.diag([16.0, 25.0, 36.0]), b.linear.field_covariance, rtol=1e-6,
                               atol=1e-9 * np.max(b.linear.field_covariance))
    axes, radius = expanded_at(cal, h, b.linear.grid_temp_c)
    k = cal.uncertainty["coverage_factor"]  # the field's, from its effective degrees of freedom
    assert 2.0 < k < 2.1
    np.testing.assert_allclose(axes, k * np.sqrt(np.einsum("gii->gi", cov)), rtol=1e-12)
    # the 3-D radius lies between the largest axis's 1.96 sigma and the isotropic 2.80 sigma of it
    top = np.sqrt(np.max(np.linalg.eigvalsh(cov), axis=1))
    assert np.all(radius >= 1.95 * top) and np.all(radius <= 2.81 * top)


def test_the_file_round_trips_the_covariance_exactly_and_old_files_load(tmp_path):
    cal, _ = _calibrated(2)
    path = tmp_path / "cal.yaml"
    calfile.save(cal, path)
    back = calfile.load(path)
    assert np.array_equal(np.asarray(back.uncertainty["covariance"]["matrix"]),
                          np.asarray(cal.uncertainty["covariance"]["matrix"]))
    assert back.uncertainty["model_error_nt"] == [4.0, 5.0, 6.0]
    old = cal.to_dict()
    del old["uncertainty"]["covariance"], old["uncertainty"]["model_error_nt"]
    legacy = Calibration.from_dict(old)
    cov, correlated = parameter_covariance(legacy)
    factors = legacy.uncertainty["coverage_factors"]  # each parameter's own k
    assert not correlated and np.allclose(np.diag(cov), np.concatenate(
        [np.ravel(np.asarray(legacy.uncertainty["expanded"][k]) / factors[k]) for k in legacy.params]) ** 2)
    expanded_at(legacy, np.array([[30_000.0, 0.0, 40_000.0]]), np.array([25.0]))  # usable, uncorrelated


@pytest.mark.parametrize("change, message", [
    (lambda c: c.update(parameters=c["parameters"][::-1]), "must list the parameters in order"),
    (lambda c: c.update(matrix=np.eye(3).tolist()), "symmetric 24x24"),
    (lambda c: c["matrix"][0].__setitem__(1, 5.0), "symmetric 24x24"),
])
def test_a_malformed_covariance_is_refused_in_one_line(change, message):
    cal, _ = _calibrated(3)
    data = cal.to_dict()
    change(data["uncertainty"]["covariance"])
    with pytest.raises(DataError, match=message) as info:
        Calibration.from_dict(data, where="cal.yaml")
    said = str(info.value)
    assert said.startswith("cal.yaml: key 'uncertainty.covariance.") and "\n" not in said


@pytest.mark.parametrize("change, key", [
    (lambda u: u["coverage_factors"].update(S=[2.0, 2.0]), "coverage_factors.S"),
    (lambda u: u["coverage_factors"].update(S="two"), "coverage_factors.S"),
    (lambda u: u["coverage_factors"].update(nope=[2.0]), "coverage_factors.nope"),
    (lambda u: u["coverage_factors"]["b_nt"].__setitem__(0, -2.0), "coverage_factors.b_nt"),
    (lambda u: u.update(coverage_factors=[2.0]), "coverage_factors"),
    (lambda u: u.update(field_effective_dof=-4), "field_effective_dof"),
    (lambda u: u.update(expanded_norm_error_nt="wide"), "expanded_norm_error_nt"),
    (lambda u: u.update(expanded_norm_error_nt=-1.0), "expanded_norm_error_nt"),
])
def test_malformed_coverage_factors_are_refused_in_one_line(change, key):
    cal, _ = _calibrated(3)
    data = cal.to_dict()
    change(data["uncertainty"])
    with pytest.raises(DataError) as info:
        Calibration.from_dict(data, where="cal.yaml")
    said = str(info.value)
    assert said.startswith(f"cal.yaml: key 'uncertainty.{key}'") and "\n" not in said


def test_a_thermal_state_is_its_two_point_mixture_not_a_normal_error(tmp_path):
    """A file with the DUT's thermal state (+-d per axis): the covariance counts d^2, the radius is the
    mixture's (95 % of draws of the parameters' error plus +-d), below a normal radius of that covariance;
    the key round-trips, and a negative value is refused in one line."""
    cal, b = _calibrated(4)
    d = [120.0, 80.0, 40.0]
    cal.uncertainty = {**cal.uncertainty, "hysteresis_state_nt": d}
    h, temps = b.linear.grid_h_nt[:6], b.linear.grid_temp_c[:6]
    cov = field_covariance(cal, h, temps)
    without = field_covariance(Calibration.from_dict({**cal.to_dict(), "uncertainty": {
        k: v for k, v in cal.uncertainty.items() if k != "hysteresis_state_nt"}}), h, temps)
    np.testing.assert_allclose(cov - without, np.broadcast_to(np.diag(np.square(d)), cov.shape), rtol=1e-9)
    _, radius = expanded_at(cal, h, temps)
    rng = np.random.default_rng(0)
    for n in range(len(h)):
        x = rng.multivariate_normal(np.zeros(3), without[n], 200_000)
        x += rng.choice([-1.0, 1.0], (len(x), 3)) * d
        assert np.mean(np.linalg.norm(x, axis=1) <= radius[n]) == pytest.approx(0.95, abs=0.003)
    from calib.stats.distributions import gaussian_radius

    assert np.all(radius < gaussian_radius(cov))
    path = tmp_path / "state.yaml"
    calfile.save(cal, path)
    assert calfile.load(path).uncertainty["hysteresis_state_nt"] == d
    data = cal.to_dict()
    data["uncertainty"]["hysteresis_state_nt"] = [1.0, -2.0, 0.0]
    with pytest.raises(DataError, match=r"^cal.yaml: key 'uncertainty.hysteresis_state_nt' must be 3"):
        Calibration.from_dict(data, where="cal.yaml")


@pytest.mark.parametrize("state", [None, [120.0, 80.0, 40.0]])
def test_the_interval_of_the_field_size_holds_95_percent_of_its_errors(state):
    """The interval of |B|'s error (what a scalar fit answers for): 95 % of draws of the field's error (the
    parameters' covariance and the model error, normal; with a thermal state, +-d per axis, each sign on
    its own) change |B| by no more than it; it is narrower than the 3-D radius."""
    cal, b = _calibrated(5)
    if state is not None:
        cal.uncertainty = {**cal.uncertainty, "hysteresis_state_nt": state}
    h, temps = b.linear.grid_h_nt[:6], b.linear.grid_temp_c[:6]
    normal = field_covariance(cal, h, temps) - np.diag(np.square(state or [0.0, 0.0, 0.0]))
    size_u = expanded_norm_at(cal, h, temps)
    field = cal.apply(h, temps)
    rng = np.random.default_rng(1)
    for n in range(len(h)):
        x = rng.multivariate_normal(np.zeros(3), normal[n], 200_000)
        if state is not None:
            x += rng.choice([-1.0, 1.0], (len(x), 3)) * state
        change = np.linalg.norm(field[n] + x, axis=1) - np.linalg.norm(field[n])
        assert np.mean(np.abs(change) <= size_u[n]) == pytest.approx(0.95, abs=0.003)
    assert np.all(size_u < expanded_at(cal, h, temps)[1])
