"""A calibration's uncertainty at any reading and temperature, from its file alone: the parameters' full
covariance C (`uncertainty.covariance`) through the calibrated field's derivative F at that reading, plus
the model error no parameter carries (`uncertainty.model_error_nt`, per axis, normal) and the DUT's
thermal state at the point of use (`uncertainty.hysteresis_state_nt`, per axis: +-d, either sign equally
likely, a two-point distribution as the budget draws it):

    cov = field_covariance(cal, h_nt, temp_c)     # (N,3,3): F C F^T + diag(model_error^2 + d^2)
    u_axes, radius = expanded_at(cal, h_nt, temp_c)   # k u per axis (N,3), the 95 % radius (N,)
    u_norm = expanded_norm_at(cal, h_nt, temp_c)      # the 95 % interval of |B|'s error (N,)

The radius holds 95 % of the 3-D error; the |B| interval 95 % of the error of the field's size, what a
scalar fit answers for (the covariance along the field's own direction, the state's +-d projected on it).
Normal errors alone: by quadrature (calib.stats.distributions). With a thermal state the error is a normal one
shifted by +-d, whose radius a normal of the same covariance overstates (for a state that dominates, by
about 1.6x): it is then that mixture's own (calib.stats.distributions shifted_radius, shifted_interval).

A file from before the covariance was written has only each parameter's expanded uncertainty: then C is
diag((U / k)^2) and `correlated` says so (the parameters' correlations, large between a scale and its
temperature coefficient, are lost: the figures are then only indicative).
"""

from __future__ import annotations

import numpy as np

from calib.calibration import Calibration, standard_uncertainty
from calib.errors import DataError
from calib.stats.distributions import gaussian_radius, shifted_interval, shifted_radius
from calib.stats.student import widening
from calib.uncertainty.linearise import ParamLayout, field_jacobian

CHUNK_ROWS = 20_000
STATE_CHUNK_ROWS = 256  # rows per block of the radius with a thermal state (x 4 signs x 200 directions)
SHARED_TO = 1e-3
# the sign patterns of +-d, each with its negation (the same by the normal part's symmetry): the budget
# draws each axis's sign on its own
_SIGNS = np.array([[1.0, 1.0, 1.0], [1.0, 1.0, -1.0], [1.0, -1.0, 1.0], [-1.0, 1.0, 1.0]])


def parameter_covariance(cal: Calibration) -> tuple[np.ndarray, bool]:
    """(C (P,P) in ParamLayout order, whether it holds the correlations)."""
    u = cal.uncertainty
    if u is None:
        raise DataError("the calibration states no uncertainty (no `uncertainty:` section)")
    layout = ParamLayout.of(cal.params)
    stated = u.get("covariance")
    if stated is not None and stated.get("parameters") == layout.labels():
        return np.asarray(stated["matrix"], float), True
    flat = layout.flatten({n: standard_uncertainty(u, n) for n in cal.params})
    return np.diag(flat**2), False


def hysteresis_state_nt(cal: Calibration) -> np.ndarray:
    """(3,): the +-d per axis of the DUT's thermal state at a point of use (zeros: none stated)."""
    return np.asarray(cal.uncertainty.get("hysteresis_state_nt") or np.zeros(3), float)


def field_covariance(cal: Calibration, h_nt, temp_c=None) -> np.ndarray:
    """(N,3,3): the calibrated field's covariance at raw readings h_nt (N,3) and temperatures (N,)."""
    return _normal_covariance(cal, h_nt, temp_c) + np.diag(hysteresis_state_nt(cal) ** 2)


def _normal_covariance(cal: Calibration, h_nt, temp_c=None) -> np.ndarray:
    """(N,3,3): field_covariance without the thermal state: the normal part of the error."""
    h = np.atleast_2d(np.asarray(h_nt, float))
    t = None if temp_c is None else np.broadcast_to(np.asarray(temp_c, float), (len(h),))
    cov, _ = parameter_covariance(cal)
    model = np.asarray(cal.uncertainty.get("model_error_nt") or np.zeros(3), float)
    out = np.empty((len(h), 3, 3))
    for lo in range(0, len(h), CHUNK_ROWS):
        rows = slice(lo, min(lo + CHUNK_ROWS, len(h)))
        f = field_jacobian(cal, h[rows], None if t is None else t[rows])  # (m,3,P)
        out[rows] = np.einsum("mip,pq,mjq->mij", f, cov, f, optimize=True)
    out += np.diag(model**2)
    return out


def expanded_at(cal: Calibration, h_nt, temp_c=None) -> tuple[np.ndarray, np.ndarray]:
    """(k u per axis (N,3), the radius holding 95 % of the 3-D error (N,)) at every reading."""
    normal = _normal_covariance(cal, h_nt, temp_c)
    state = hysteresis_state_nt(cal)
    k = float(cal.uncertainty["coverage_factor"])
    axes = k * np.sqrt(np.clip(np.einsum("nii->ni", normal) + state**2, 0.0, None))
    if not np.any(state > 0):
        radius = np.empty(len(normal))
        for lo in range(0, len(normal), CHUNK_ROWS):
            radius[lo:lo + CHUNK_ROWS] = gaussian_radius(normal[lo:lo + CHUNK_ROWS])
        return axes, radius * _widening(cal)
    # readings of one point differ by their noise alone: covariances rounded to a power-of-two step near
    # SHARED_TO of their trace share one radius (it moves by less than that), so a long session costs its
    # points, not its rows; the radius is the rounded covariance's, whichever rows are asked for
    power = np.round(np.log2(SHARED_TO * np.maximum(np.einsum("nii->n", normal), np.finfo(float).tiny)))
    keys = np.column_stack([power, np.round(normal.reshape(len(normal), 9) / 2.0 ** power[:, None])])
    distinct, which = np.unique(keys, axis=0, return_inverse=True)
    rounded = distinct[:, 1:].reshape(-1, 3, 3) * 2.0 ** distinct[:, :1, None]
    unique = np.empty(len(distinct))
    for lo in range(0, len(distinct), STATE_CHUNK_ROWS):
        unique[lo:lo + STATE_CHUNK_ROWS] = shifted_radius(rounded[lo:lo + STATE_CHUNK_ROWS], _SIGNS * state)
    return axes, unique[which.ravel()] * _widening(cal)


def expanded_norm_at(cal: Calibration, h_nt, temp_c=None) -> np.ndarray:
    """(N,): the half-width holding 95 % of the error of |B| (the calibrated field's size) at every reading:
    the normal part's variance along the field's direction, beside the thermal state's +-d projected on it
    (each axis's sign on its own), widened as the radius is for few degrees of freedom."""
    along = np.atleast_2d(cal.apply(np.atleast_2d(np.asarray(h_nt, float)), temp_c))
    along = along / np.linalg.norm(along, axis=1, keepdims=True)
    variance = np.einsum("ni,nij,nj->n", along, _normal_covariance(cal, h_nt, temp_c), along)
    shifts = along @ (_SIGNS * hysteresis_state_nt(cal)).T  # (N,4): with their negations, by symmetry
    return shifted_interval(np.sqrt(np.clip(variance, 0.0, None)), shifts) * _widening(cal)


def _widening(cal: Calibration) -> float:
    """The factor a 95 % radius made for known inputs widens by where the field's effective degrees of
    freedom are few (the budget's field_effective_dof): t_97.5(nu) / 1.96; 1 for a file without them."""
    dof = cal.uncertainty.get("field_effective_dof")
    return 1.0 if dof is None else widening(float(dof))
