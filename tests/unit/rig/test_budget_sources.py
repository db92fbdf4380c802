"""The budget's sources on data whose answer is known: each loop's place, lean and turns against the
simulator's own Biot-Savart, what the commissioning's settings show (non-linearity, hysteresis, the
read-back's error, drift between repeats), the thermal direction, the misfit beyond the noise within
points and the offset's wander between steps."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from calib.dataset import Dataset
from drivers.sim.world.coilfield import CoilGeometry as SimGeometry
from drivers.sim.world.coilfield import LoopErrors, coil_matrix_at
from rig.budget.misfit import misfit_source, within_point_noise
from rig.budget.modelerror import thermal_direction
from rig.budget.wander import WANDER_FACTOR, wander_source
from rig.fieldsources.coils import commissioned
from rig.fieldsources.coils.config import DeclaredGeometry
from rig.fieldsources.coils.loops import PER_LOOP, loop_sensitivity, matrix_with_loops

CENTRE = np.array([[50480.0, 264.0, 0.0], [0.0, 49510.0, -263.0], [0.0, 0.0, 50310.0]])
GEOMETRY = DeclaredGeometry(shape="square", size_m=(0.4, 0.4, 0.4), spacing_m=(0.2178, 0.2178, 0.2178))


def test_each_loop_off_its_drawing_matches_the_simulators_biot_savart():
    """The rig's closed forms, loop by loop, against drivers/sim/world/coilfield.py's numerical
    integration."""
    rng = np.random.default_rng(1)
    deviations = np.zeros((3, 2, PER_LOOP))
    deviations[..., :3] = rng.uniform(-0.7, 0.7, (3, 2, 3))
    deviations[..., 3] = rng.uniform(-0.15, 0.15, (3, 2))
    deviations[..., 4] = rng.uniform(-1800, 1800, (3, 2))
    loops = {j: LoopErrors(turns_error_ppm=tuple(deviations[j, :, 4]),
                           offset_m=tuple(tuple(v / 1000.0) for v in deviations[j, :, :3]),
                           tilt_deg=tuple(deviations[j, :, 3])) for j in range(3)}
    sim = SimGeometry("square", GEOMETRY.size_m, GEOMETRY.spacing_m)
    for position_mm in ([70.0, 0.0, 0.0], [0.0, -50.0, 30.0], [40.0, 40.0, -40.0]):
        point = np.asarray(position_mm) / 1000.0
        ours = matrix_with_loops(CENTRE, "square", GEOMETRY.size_m, GEOMETRY.spacing_m, point, deviations)
        theirs = coil_matrix_at(CENTRE, sim, point, loops)
        ideal = coil_matrix_at(CENTRE, sim, point)
        np.testing.assert_allclose(ours, theirs, rtol=0, atol=0.02)  # nT/A: quadrature accuracy
        assert np.max(np.abs(theirs - ideal)) > 5.0  # the loops do move the field there (>5 nT/A)
    np.testing.assert_allclose(matrix_with_loops(CENTRE, "square", GEOMETRY.size_m, GEOMETRY.spacing_m,
                                                 np.zeros(3), deviations), CENTRE, rtol=1e-12, atol=1e-9)


def test_the_loop_sensitivity_predicts_a_small_deviation():
    deviation = np.zeros((3, 2, PER_LOOP))
    deviation[1, 0] = [0.3, -0.2, 0.1, 0.05, 500.0]
    deviation[2, 1] = [-0.1, 0.4, 0.0, -0.08, -800.0]
    point = np.array([60.0, -30.0, 20.0])
    moved = matrix_with_loops(CENTRE, "square", GEOMETRY.size_m, GEOMETRY.spacing_m, point / 1000, deviation)
    base = matrix_with_loops(CENTRE, "square", GEOMETRY.size_m, GEOMETRY.spacing_m, point / 1000,
                             np.zeros_like(deviation))
    predicted = np.tensordot(deviation.ravel(), loop_sensitivity(CENTRE, GEOMETRY, point), axes=1)
    np.testing.assert_allclose(base + predicted, moved, rtol=0, atol=1e-2 * np.max(np.abs(moved - base)))


def _settings(readings, currents, readback=None):
    return [SimpleNamespace(setting=tuple(c), mean_nt=tuple(r),
                            readback=None if readback is None else tuple(readback[k]))
            for k, (c, r) in enumerate(zip(currents, readings, strict=True))]


def _design(level: float = 1.2, repeats: int = 2) -> np.ndarray:
    one = [np.zeros(3)]
    for j in range(3):
        for share in (0.5, 1.0, 0.5, 0.0, -0.5, -1.0, -0.5, 0.0):
            c = np.zeros(3)
            c[j] = share * level
            one.append(c)
    for signs in np.ndindex(2, 2, 2):
        one.append(0.5 * level * (1 - 2 * np.array(signs)))
    return np.array(one * repeats)


def test_the_commissioning_settings_show_the_coils_non_linearity_and_hysteresis():
    rng = np.random.default_rng(2)
    currents = _design()
    ambient = np.array([16000.0, -300.0, 43000.0])
    quad = np.array([[30.0, 0.0, 0.0], [0.0, -20.0, 0.0], [0.0, 0.0, 0.0]])  # nT/A^2: coil x, y bend
    h_true = np.array([[0.0, 0.0, 12.0], [8.0, 0.0, 0.0], [0.0, 0.0, 0.0]])  # coil j's step, axis i
    s = commissioned.directions(currents)
    noise = 1.0
    readings = currents @ CENTRE.T + ambient + (currents**2) @ quad.T + 0.5 * s @ h_true + \
        rng.normal(0, noise, (len(currents), 3))
    c, sigma, absorbed = commissioned.nonlinearity(_settings(readings, currents))
    np.testing.assert_allclose(c[:, :3], quad, atol=5 * np.sqrt(np.max(np.diag(sigma))))
    h, cov = commissioned.hysteresis(_settings(readings, currents))
    np.testing.assert_allclose(h, h_true, atol=6 * noise)
    assert np.all(np.diag(cov) >= h.ravel() ** 2)  # u^2 + b^2 (index coil * 3 + axis): never below b^2
    # the run's error at other currents: the quadratic term less what the linear fit absorbed
    run = np.array([[0.8, 0.0, 0.0], [-0.8, 0.0, 0.0], [0.0, 0.4, 0.0]])
    a = commissioned.nonlinearity_sensitivity(run, absorbed)
    predicted = np.einsum("niq,q->ni", a, c.ravel())
    true_bend = (run**2) @ quad.T
    c_true = np.vstack([quad.T, np.zeros((3, 3))])  # (6 terms, 3 axes)
    linear_part = np.column_stack([run, np.ones(len(run))]) @ (absorbed @ c_true)
    np.testing.assert_allclose(predicted, true_bend - linear_part, atol=2.0)


def test_the_read_back_error_and_the_drift_between_repeats():
    rng = np.random.default_rng(3)
    currents = _design()
    readback = currents * (1 + np.array([230e-6, -260e-6, 220e-6])) + np.array([0.15e-3, -0.1e-3, 0.2e-3]) + \
        rng.normal(0, 0.1e-3, currents.shape)
    readings = currents @ CENTRE.T + rng.normal(0, 1.0, currents.shape)
    fit = commissioned.fit_readback(_settings(readings, currents, readback))
    np.testing.assert_allclose(fit["gain_ppm"], [230, -260, 220], atol=5 * max(fit["std_errors_gain_ppm"]))
    np.testing.assert_allclose(fit["offset_ma"], [0.15, -0.1, 0.2], atol=5 * max(fit["std_errors_offset_ma"]))
    assert commissioned.fit_readback(_settings(readings, currents)) is None  # no read-backs recorded
    still = commissioned.repeat_drift(_settings(readings, currents), 2)
    drifted = readings.copy()
    half = len(currents) // 2
    drifted[half:] += currents[half:] @ np.diag([0.0, 0.0, 30.0]).T  # coil z's constant moved by 30 nT/A
    moved = commissioned.repeat_drift(_settings(drifted, currents), 2)
    assert moved[8] == pytest.approx(30.0**2 / 2, rel=0.2)  # the variance of two values 30 apart
    assert np.all(still < 0.01 * moved[8]) and moved[0] < 0.01 * moved[8]  # noise alone: next to nothing


def test_the_thermal_direction_follows_the_history_through_a_play():
    t = np.arange(10.0)
    temps = np.array([22.0, 10.0, -20.0, -20.2, -19.8, 0.0, 0.3, 25.0, 60.0, 59.5])
    history = [(-5.0, 22.0), (-3.0, 22.1)]
    d = thermal_direction(t, temps, history)
    np.testing.assert_array_equal(d, [0, -1, -1, -1, -1, 1, 1, 1, 1, 1])  # 0.5 degC back is within the play


def _stepped(rng, noise: float, wander: float, excess: float = 0.0, step_nt: float = 30.0):
    """Four steps x 40 points x 5 samples of residuals: white noise, an offset per step (`step_nt`), a
    random walk point to point of `wander` nT, and a point-to-point misfit of `excess` nT."""
    steps, points, samples = 4, 40, 5
    rows, labels, groups, times = [], [], [], []
    t = 0.0
    for k in range(steps):
        level = rng.normal(0, step_nt, 3)
        for p in range(points):
            level = level + rng.normal(0, wander, 3)
            misfit = rng.normal(0, excess, 3)
            for _ in range(samples):
                rows.append(level + misfit + rng.normal(0, noise, 3))
                labels.append(f"T{k}-F{p}")
                groups.append(f"T{k}")
                times.append(t)
                t += 1.0
            t += 10.0
        t += 3600.0
    resid = np.array(rows)
    n = len(resid)
    ds = Dataset(np.zeros((n, 3)), np.zeros(n), np.zeros((n, 3)), group=np.array(groups, object),
                 columns={"point": np.array(labels, object), "t": np.array(times)})
    return ds, resid


def test_the_misfit_beyond_the_noise_within_points_is_found_and_noise_alone_is_not():
    rng = np.random.default_rng(4)
    ds, resid = _stepped(rng, noise=30.0, wander=0.0, excess=0.0, step_nt=0.0)
    resid = resid - resid.mean(axis=0)
    notes: list[str] = []
    quiet = misfit_source(resid, np.ones(len(resid)), len(resid) - 8, ds.columns["point"], notes)
    assert np.all(np.diag(quiet.covariance) < 3.0**2)  # noise only: no excess (or within its scatter)
    ds, resid = _stepped(rng, noise=30.0, wander=0.0, excess=40.0, step_nt=0.0)
    resid = resid - resid.mean(axis=0)
    noisy = misfit_source(resid, np.ones(len(resid)), len(resid) - 8, ds.columns["point"], notes)
    np.testing.assert_allclose(np.sqrt(np.diag(noisy.covariance)), 40.0, rtol=0.3)
    noise, dof = within_point_noise(resid, ds.columns["point"])
    np.testing.assert_allclose(noise, 30.0, rtol=0.1)


def test_the_offset_wander_between_points_sets_each_steps_offset():
    rng = np.random.default_rng(5)
    ds, resid = _stepped(rng, noise=30.0, wander=25.0)
    noise, _ = within_point_noise(resid, ds.columns["point"])
    source, said, variance = wander_source(ds, resid, noise)
    # a random walk of 25 nT per point: consecutive point means differ by 25 nT, Allan variance 312 nT^2
    assert np.mean(variance) == pytest.approx(WANDER_FACTOR * 25.0**2 / 2, rel=0.45)
    assert source.covariance.shape == (12, 12) and "Allan deviation" in said
    quiet_ds, quiet = _stepped(rng, noise=30.0, wander=0.0)
    _, _, small = wander_source(quiet_ds, quiet, within_point_noise(quiet, quiet_ds.columns["point"])[0])
    assert np.all(small < 0.3 * variance)


def test_an_error_shared_by_a_points_samples_weighs_as_n_times_its_variance():
    """Five samples a point sharing an error of 20 nT weigh in a fit like a white noise of variance
    30^2 + 5 x 20^2: the statistics take that; without a shared error they take the residual's RMS."""
    from rig.budget.modelerror import _clustered_noise

    rng = np.random.default_rng(6)
    ds, resid = _stepped(rng, noise=30.0, wander=0.0, excess=20.0, step_nt=0.0)
    notes: list[str] = []
    rms = np.sqrt(np.mean(resid**2, axis=0))
    taken = _clustered_noise(resid, ds.columns["point"], rms, notes)
    np.testing.assert_allclose(taken, np.sqrt(30.0**2 + 5 * 20.0**2), rtol=0.15)
    assert notes and "share an error" in notes[0]
    ds, white = _stepped(rng, noise=30.0, wander=0.0, excess=0.0, step_nt=0.0)
    rms = np.sqrt(np.mean(white**2, axis=0))
    assert np.array_equal(_clustered_noise(white, ds.columns["point"], rms, []), rms)


def _table_like(rng, rotation_deg: float, noise: float = 30.0):
    """A turntable's unbalanced directions (the site field at 24 orientations, 5 samples each) and a
    residual that is a small rotation of the field (what P12 cannot follow) plus noise."""
    from rig.fieldsources.fieldmaths import table_field_nt

    site = np.array([16000.0, 0.0, 43000.0])
    fields, labels = [], []
    for el in (-60.0, 0.0, 60.0):
        for az in np.arange(0.0, 360.0, 45.0):
            for _ in range(5):
                fields.append(table_field_nt(site, az, el))
                labels.append(f"F{az:g}/{el:g}")
    ref = np.array(fields)
    angle = np.radians(rotation_deg)
    skew = np.array([[0.0, -angle, 0.0], [angle, 0.0, 0.0], [0.0, 0.0, 0.0]])  # about z
    resid = ref @ skew.T + rng.normal(0, noise, ref.shape)
    return ref, resid, np.array(labels, object)


def test_a_directional_misfit_over_unbalanced_directions_is_taken_at_every_direction():
    """A rotation a model cannot follow, seen over a table's directions: the misfit states its size over
    the whole sphere (exactly |c|^2 / 3 per axis for a rotation), not its smaller size over the data."""
    from rig.budget.misfit import directional_part

    rng = np.random.default_rng(11)
    ref, resid, labels = _table_like(rng, rotation_deg=1.0)
    resid = resid - resid.mean(axis=0)  # as a fit's offsets would leave it
    notes: list[str] = []
    source = misfit_source(resid, np.ones(len(resid)), len(resid) - 9, labels, notes, ref)
    # a 1 deg turn about z errs by theta (-B_y, B_x): over every direction at |B|, theta |B| / sqrt(3) per
    # axis. The table's directions hold less B_y than that (x grows to it) and more B_x (y keeps its own).
    over_sphere = np.radians(1.0) * np.sqrt(np.mean(np.sum(ref**2, axis=1)) / 3)
    in_data = np.sqrt(np.mean(resid**2, axis=0))
    stated = np.sqrt(np.diag(source.covariance))
    np.testing.assert_allclose(stated[0], over_sphere, rtol=0.05)
    assert in_data[0] < 0.5 * over_sphere and stated[1] >= in_data[1] > over_sphere
    assert "over every direction" in source.origin
    quiet_ref, quiet, quiet_labels = _table_like(rng, rotation_deg=0.0)
    assert directional_part(quiet - quiet.mean(axis=0), quiet_ref, np.ones(len(quiet)), quiet_labels) is None


@pytest.mark.parametrize("model", ["p12", "scalar"])
def test_another_models_parameters_carry_the_thermal_hysteresis_t24_finds(model):
    """A DUT whose offset stands +-c apart heating and cooling, the steps mostly heating: P12's and the
    scalar fit's offsets take the imbalance as T24's do. Their budget carries the hysteresis as T24's
    checks estimate it (u^2 + b^2, b the estimate), and the thermal state at a point of use; without a
    hysteresis, neither."""
    import calib
    from calib import synthetic
    from rig.budget.modelerror import model_sources

    rng = np.random.default_rng(21)
    steps = [-20.0, 0.0, 25.0, 60.0, 10.0]  # heating to 60, then cooling to 10
    temps_dirs = {-20.0: 0.0, 0.0: 1.0, 25.0: 1.0, 60.0: 1.0, 10.0: -1.0}
    c = np.array([150.0, -100.0, 80.0])
    named = {}
    for hysteresis in (c, np.zeros(3)):
        ds, _ = synthetic.t24_dataset(rng, temps_c=steps, samples_per_point=4, noise_nt=20.0,
                                      temp_jitter_c=0.0)
        direction = np.array([temps_dirs[t] for t in ds.temp_c])
        ds.h_nt = ds.h_nt + direction[:, None] * hysteresis
        labels = [f"T{g}-F{i // 4 % 26}" for i, g in enumerate(ds.group)]
        ds.columns["point"] = np.array(labels, object)
        cal = calib.fit(ds, model, **({"temperature_terms": True} if model == "scalar" else {}))
        sources, _, _, _ = model_sources(ds, cal, direction)
        names = [s.name for s in sources]
        named[bool(hysteresis.any())] = names
        if hysteresis.any():
            assert "model checks (hysteresis)" in names and "thermal hysteresis state" in names
            line = sources[names.index("model checks (hysteresis)")]
            at = [np.flatnonzero(np.abs(line.ref_nt[:, i, :]).sum(axis=0))[0] for i in range(3)]
            stated = np.sqrt([line.covariance[k, k] for k in at])
            np.testing.assert_allclose(stated, np.abs(c), rtol=0.25)  # the estimate and its u
    assert "model checks (hysteresis)" not in named[False]


def test_p12s_statistics_and_wander_come_from_the_noise_not_from_what_p12_cannot_follow():
    """A DUT P12 cannot follow (its cross-axis terms turn the field, its scale changes with temperature):
    P12's residual is mostly that misfit, which its misfit line states once. Taken also as the readings'
    noise it would widen the parameters' statistics tenfold, and from one point to the next it would pass
    for an offset wander. The fit's statistics take the noise T24 with its checks' terms leaves, and the
    parameters' stated spread is their spread over fresh noise."""
    import calib
    from calib import synthetic
    from calib.uncertainty.linearise import linearised
    from rig.budget.modelerror import model_sources

    rng = np.random.default_rng(31)
    noise_nt, samples = 20.0, 5
    clean, _ = synthetic.t24_dataset(rng, temps_c=[-20.0, 0.0, 25.0, 60.0], samples_per_point=samples,
                                     noise_nt=0.0, temp_jitter_c=0.0)
    n = len(clean)
    labels = np.array([f"T{g}-F{i // samples % 26}" for i, g in enumerate(clean.group)], object)

    def noisy() -> Dataset:
        return Dataset(clean.h_nt + rng.normal(0, noise_nt, (n, 3)), clean.temp_c, clean.ref_nt,
                       group=clean.group, columns={"point": labels, "t": np.arange(n) * 2.0})

    ds = noisy()
    cal = calib.fit(ds, "p12")
    sources, notes, noise, _ = model_sources(ds, cal, None)
    names = [s.name for s in sources]
    misfit = np.sqrt(np.diag(sources[names.index("misfit")].covariance))
    assert np.all(misfit > 5 * noise_nt)  # what P12 cannot follow, stated once
    wander = sources[names.index("offset wander")].covariance
    assert not np.any(wander)  # white noise: nothing wanders from one point to the next
    np.testing.assert_allclose(noise, noise_nt, rtol=0.15)  # the fitted field's noise: S ~ 1
    lin = linearised(ds, cal)
    own = np.sqrt(np.diag(lin.statistical_covariance()))
    lin.take_noise(noise)
    stated = np.sqrt(np.diag(lin.statistical_covariance()))
    spread = np.std([np.concatenate([np.ravel(v) for v in calib.fit(noisy(), "p12").params.values()])
                     for _ in range(300)], axis=0)
    np.testing.assert_allclose(stated, spread, rtol=0.2)
    assert np.all(own > 3 * spread)  # the residual's reading of the noise


def test_the_shared_error_is_read_from_a_fits_residual_with_the_parameters_share_put_back():
    """The point means of a fit's residual have lost the share of their scatter its parameters took (K
    points, p parameters: K - p of K): the shared error is read with it put back. Here 15 parameters over
    30 points would halve it."""
    from rig.budget.modelerror import _clustered_noise

    rng = np.random.default_rng(12)
    points, samples, params, shared, white = 30, 5, 15, 20.0, 10.0
    labels = np.repeat([f"P{k}" for k in range(points)], samples).astype(object)
    design = np.repeat(rng.normal(size=(points, params)), samples, axis=0)  # the same regressors a point
    hat = design @ np.linalg.pinv(design)
    taken = []
    for _ in range(40):
        error = np.repeat(rng.normal(0, shared, (points, 3)), samples, axis=0)
        error = error + rng.normal(0, white, error.shape)
        resid = error - hat @ error
        rms = np.sqrt(np.sum(resid**2, axis=0) / (len(labels) - params))
        taken.append([_clustered_noise(resid, labels, rms, [], params),
                      _clustered_noise(resid, labels, rms, [])])
    with_share, without = np.mean(taken, axis=0)
    expected = np.sqrt(white**2 + samples * shared**2)
    np.testing.assert_allclose(with_share, expected, rtol=0.1)
    assert np.all(without < 0.8 * expected)
