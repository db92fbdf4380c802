"""A calibration's uncertainty at any reading and temperature, from its file alone: the parameters' full
covariance C (`uncertainty.covariance`) through the calibrated field's derivative F at that reading, plus
the model error no parameter carries (`uncertainty.model_error_nt`, per axis):

    cov = field_covariance(cal, h_nt, temp_c)     # (N,3,3): F C F^T + diag(model_error^2)
    u_axes, radius = expanded_at(cal, h_nt, temp_c)   # k u per axis (N,3), the 95 % radius (N,)

A file from before the covariance was written has only each parameter's expanded uncertainty: then C is
diag((U / k)^2) and `correlated` says so (the parameters' correlations, large between a scale and its
temperature coefficient, are lost: the figures are then only indicative).
"""

from __future__ import annotations

import numpy as np

from calib.calibration import Calibration
from calib.distributions import gaussian_radius
from calib.errors import DataError
from calib.linearise import ParamLayout, field_jacobian

CHUNK_ROWS = 20_000


def parameter_covariance(cal: Calibration) -> tuple[np.ndarray, bool]:
    """(C (P,P) in ParamLayout order, whether it holds the correlations)."""
    u = cal.uncertainty
    if u is None:
        raise DataError("the calibration states no uncertainty (no `uncertainty:` section)")
    layout = ParamLayout.of(cal.params)
    stated = u.get("covariance")
    if stated is not None and stated.get("parameters") == layout.labels():
        return np.asarray(stated["matrix"], float), True
    k = float(u["coverage_factor"])
    flat = layout.flatten({n: np.asarray(u["expanded"][n], float) / k for n in cal.params})
    return np.diag(flat**2), False


def field_covariance(cal: Calibration, h_nt, temp_c=None) -> np.ndarray:
    """(N,3,3): the calibrated field's covariance at raw readings h_nt (N,3) and temperatures (N,)."""
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
    cov = field_covariance(cal, h_nt, temp_c)
    k = float(cal.uncertainty["coverage_factor"])
    axes = k * np.sqrt(np.clip(np.einsum("nii->ni", cov), 0.0, None))
    radius = np.empty(len(cov))
    for lo in range(0, len(cov), CHUNK_ROWS):
        radius[lo:lo + CHUNK_ROWS] = gaussian_radius(cov[lo:lo + CHUNK_ROWS])
    return axes, radius
