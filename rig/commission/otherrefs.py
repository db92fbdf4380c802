"""The ambient at the station's other reference magnetometers, read during `rig commission` beside the one
that commissions the coils: each one sitting elsewhere shows the lab field's gradient between the two
(rig/fieldsources/coils/gradientfit.py), as a move of the one reference does (rig/commission/places.py).

With the coils at 0 A, settled, both are read together, so the lab field's drift cancels in their
difference, and it is the difference that is recorded and fitted (G times the offset between the two):
the commissioning's own ambient, in both, is not counted twice. Two instruments do not share their
calibration errors as one moved does:
the difference carries both calibrations' covariance at what each read (calib/uncertainty/propagation.py
reference_source), besides both readings' standard errors.

    others = other_ambients(rig, station, primary, calibrations)   # [{name, position_mm, difference...}]
"""

from __future__ import annotations

import logging

import numpy as np

from calib.uncertainty.fielderror import parameter_covariance
from calib.uncertainty.propagation import reference_source
from rig.config.station import SAME_PLACE_MM
from rig.core.errors import DeviceError
from rig.reference.sitefield import COMMISSION_SETTLE_S, ReferenceReader, readback_mean, settle_at

log = logging.getLogger("magrig.commission")


def _position(ref) -> np.ndarray:
    return np.zeros(3) if ref.position_mm is None else np.asarray(ref.position_mm, float)


def elsewhere(station, primary) -> list:
    """The station's other reference magnetometers that sit away from `primary`."""
    here = _position(primary)
    return [r for r in station.reference_magnetometers
            if r.name != primary.name and np.linalg.norm(_position(r) - here) >= SAME_PLACE_MM]


def _calibration_covariance(ref, calibration, measured_nt, temp_c) -> np.ndarray:
    """(3, 3): what the reference's calibration error does to the field it reported (its `uncertainty:`
    is there: rig/reference/sitefield.py refuses a reference calibration without one)."""
    source = reference_source(ref.name, np.asarray(measured_nt, float)[None], calibration,
                              parameter_covariance(calibration)[0], temp_c)
    a = source.ref_nt[0]
    return a @ np.asarray(source.covariance, float) @ a.T


def other_ambients(rig, station, primary, calibrations) -> list[dict]:
    """Each other reference's reading less the commissioning reference's, taken together with the coils
    at 0 A (their own field as the supply's read-back says taken out of each), with its covariance. One
    that cannot be read is left out with a warning: the commissioning does not depend on it."""
    others = elsewhere(station, primary)
    if not others:
        return []
    source = station.field_source
    settle_at(rig, source, source.measurement_setting(), COMMISSION_SETTLE_S)
    readback = readback_mean(rig, source)

    def read(ref):
        m = ReferenceReader(rig, ref, calibrations[ref.name]).read_mean(
            f"commission: the ambient at {ref.name}", flagged_is_fault=True)
        own = None if readback is None else source.own_field_nt(*readback, ref.position_mm)
        return m if own is None else m.without(*own)

    main = read(primary)
    main_cov = np.diag(np.square(main.std_error_nt)) + _calibration_covariance(
        primary, calibrations[primary.name], main.vector_nt, main.temp_c)
    out = []
    for ref in others:
        try:
            m = read(ref)
        except DeviceError as exc:  # the commissioning stands without it: the gradient keeps the rest
            log.warning("commission: %s left out of the ambient gradient: %s", ref.name, exc)
            continue
        cov = main_cov + np.diag(np.square(m.std_error_nt)) + _calibration_covariance(
            ref, calibrations[ref.name], m.vector_nt, m.temp_c)
        out.append({"name": ref.name, "position_mm": [float(v) for v in _position(ref)],
                    "difference_nt": [float(v) for v in m.vector_nt - main.vector_nt],
                    "covariance": [[float(v) for v in row] for row in 0.5 * (cov + cov.T)]})
    return out
