"""The loops fitted to matrices measured at several places (rig/fieldsources/coils/loopfit.py): sim-lab's
loops, as the simulator's own Biot-Savart gives their matrices at the centre and +-70 mm on each axis with
a commissioning's noise, are recovered well enough to give the field at every DUT of sim-commissioned;
the centre alone identifies none of them."""

from __future__ import annotations

import numpy as np
import yaml

from drivers.sim.world.coilfield import CoilGeometry as SimGeometry
from drivers.sim.world.coilfield import LoopErrors, coil_matrix_at
from rig.config import CONFIGS_DIR
from rig.fieldsources.coils.config import DeclaredGeometry
from rig.fieldsources.coils.loopfit import N_LOOP, Place, fit_loops, quantity_names
from rig.fieldsources.coils.loops import PER_LOOP, matrix_with_loops

CENTRE = np.array([[50480.0, 264.0, 0.0], [0.0, 49510.0, -263.0], [0.0, 0.0, 50310.0]])
GEOMETRY = DeclaredGeometry(shape="square", size_m=(0.4, 0.4, 0.4), spacing_m=(0.2178, 0.2178, 0.2178),
                            tolerance_mm=0.5)
SE_NT_PER_A = 0.25  # a commissioning's standard error of each matrix element (sim-commissioned: 0.23-0.25)
DUTS_MM = [(70, 0, 0), (-70, 0, 0), (0, 50, 0), (0, -50, 30), (40, 40, -40), (-35, 30, 60)]


def _sim_lab_loops() -> tuple[np.ndarray, dict[int, LoopErrors]]:
    spec = yaml.safe_load((CONFIGS_DIR / "stations" / "sim-lab.yaml").read_text())["sim"]["coil_loops"]
    deviations = np.zeros((3, 2, PER_LOOP))
    loops = {}
    for j, axis in enumerate("xyz"):
        s = spec[axis]
        deviations[j, :, :3], deviations[j, :, 3], deviations[j, :, 4] = (
            s["offset_mm"], s["tilt_deg"], s["turns_error_ppm"])
        loops[j] = LoopErrors(turns_error_ppm=tuple(s["turns_error_ppm"]), tilt_deg=tuple(s["tilt_deg"]),
                              offset_m=tuple(tuple(np.asarray(v) / 1000.0) for v in s["offset_mm"]))
    return deviations, loops


def _measured(places_mm, loops, rng) -> list[Place]:
    sim = SimGeometry("square", GEOMETRY.size_m, GEOMETRY.spacing_m)
    return [Place(np.asarray(p, float), coil_matrix_at(CENTRE, sim, np.asarray(p) / 1000.0, loops)
                  + rng.normal(0.0, SE_NT_PER_A, (3, 3)), np.eye(9) * SE_NT_PER_A**2) for p in places_mm]


def test_the_loops_of_sim_lab_are_recovered_from_six_places_and_give_the_field_at_every_dut():
    truth, loops = _sim_lab_loops()
    places = [(s * 70.0 * e).tolist() for e in np.eye(3) for s in (1, -1)]
    fit = fit_loops(CENTRE, np.eye(9) * SE_NT_PER_A**2, GEOMETRY, _measured(places, loops,
                                                                            np.random.default_rng(3)), 0.1)
    sim = SimGeometry("square", GEOMETRY.size_m, GEOMETRY.spacing_m)
    for position in DUTS_MM:
        point = np.asarray(position) / 1000.0
        true = coil_matrix_at(CENTRE, sim, point, loops)
        drawn = matrix_with_loops(CENTRE, "square", GEOMETRY.size_m, GEOMETRY.spacing_m, point,
                                  np.zeros_like(truth))
        fitted = matrix_with_loops(CENTRE, "square", GEOMETRY.size_m, GEOMETRY.spacing_m, point,
                                   fit.deviations)
        assert np.max(np.abs(drawn - true)) > 15.0  # the loops do matter there (nT/A)
        assert np.max(np.abs(fitted - true)) < 2.5, position  # 5 % of what they do, at most
    # every quantity the places identify is found within 5 of its standard errors (shrinkage included)
    identified = fit.remaining < 0.5
    assert identified.sum() >= 12  # the shifts across each loop's axis at least
    off = np.abs(fit.deviations.ravel() - truth.ravel())[identified] / fit.std_errors[identified]
    assert np.all(off < 5.0), dict(zip(np.array(quantity_names())[identified], off.round(1), strict=True))
    assert fit.chi2 < 2.0 * fit.dof  # the model holds to the noise
    assert np.all(np.linalg.eigvalsh(fit.covariance) > 0)


def test_the_centre_alone_identifies_no_loop_quantity():
    _, loops = _sim_lab_loops()
    fit = fit_loops(CENTRE, np.eye(9) * SE_NT_PER_A**2, GEOMETRY,
                    _measured([(0.0, 0.0, 0.0)], loops, np.random.default_rng(4)), 0.1)
    assert fit.unidentified == quantity_names() and len(fit.unidentified) == N_LOOP
    np.testing.assert_allclose(fit.remaining, 1.0, atol=1e-3)  # the tolerance stays
    np.testing.assert_allclose(fit.deviations, 0.0, atol=1e-3 * np.max(GEOMETRY.turns_tolerance_ppm))
