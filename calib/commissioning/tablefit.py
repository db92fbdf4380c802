"""Commissioning maths for a two-axis turntable: how its axes differ from the drawing, from a rotation
sequence that a reference magnetometer on the table measures.

The ideal table turns the site field into the table frame as Ry(el)^T Rz(az)^T B_site. A real one has its
azimuth axis tilted, its elevation axis not quite perpendicular to it, zero offsets on both encoders,
and the reference (the frame every DUT is calibrated in) not quite square on the plate. What a single,
steady site field lets a reference on the table see is seven numbers:

    B(az, el) = R(m)^T Ry(el)^T Rx(delta)^T Rz(az)^T v

- v: the site field in the azimuth stage's frame (3; the azimuth axis' tilt and zero offset only turn
  the site field about, so they are in v and cannot be told apart from it),
- delta: the elevation axis' tilt towards the azimuth axis (deg),
- m: the rotation (small-angle vector, deg) from the elevation stage to the reference's frame; its
  component about y is the elevation encoder's zero offset.
Fitted by Gauss-Newton with a numerical Jacobian, scaled; the covariance is sigma^2 (J'J)^-1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from calib.errors import FitError

PARAM_NAMES = ("v_x_nt", "v_y_nt", "v_z_nt", "el_axis_tilt_deg", "mount_x_deg", "el_zero_deg", "mount_z_deg")
RCOND_SINGULAR = 1e-10
MAX_ITER = 50


def _rot(axis: int, rad: np.ndarray) -> np.ndarray:
    """(K,3,3) rotations about a coordinate axis."""
    c, s = np.cos(rad), np.sin(rad)
    out = np.zeros((len(rad), 3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    out[:, axis, axis] = 1.0
    out[:, i, i], out[:, j, j] = c, c
    out[:, i, j], out[:, j, i] = -s, s
    return out


def rotation_from_vector(m_deg) -> np.ndarray:
    """The rotation whose rotation vector is m (degrees)."""
    theta = np.radians(np.asarray(m_deg, float))
    angle = float(np.linalg.norm(theta))
    if angle < 1e-15:
        return np.eye(3)
    k = theta / angle
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * kx + (1 - math.cos(angle)) * (kx @ kx)


def table_field_nt(params, angles_deg) -> np.ndarray:
    """(K,3) field in the reference's frame at table angles (K,2) [az, el] deg, for PARAM_NAMES params."""
    p = np.asarray(params, float)
    angles = np.radians(np.atleast_2d(np.asarray(angles_deg, float)))
    v = p[:3]
    rz_t = np.transpose(_rot(2, angles[:, 0]), (0, 2, 1))
    ry_t = np.transpose(_rot(1, angles[:, 1]), (0, 2, 1))
    rx_t = _rot(0, np.radians([p[3]]))[0].T
    mount_t = rotation_from_vector(p[4:7]).T
    return np.einsum("ij,kjl,lm,kmn,n->ki", mount_t, ry_t, rx_t, rz_t, v)


def site_from_home(params, home_reading_nt) -> np.ndarray:
    """v for a table with these axes whose reference reads `home_reading_nt` at (0, 0): how a site field
    measured at home at the start of a run carries into the commissioned model."""
    p = np.asarray(params, float)
    rx = _rot(0, np.radians([p[3]]))[0]
    return rx @ rotation_from_vector(p[4:7]) @ np.asarray(home_reading_nt, float)


@dataclass
class TableFit:
    params: np.ndarray  # PARAM_NAMES order
    covariance: np.ndarray  # 7x7
    residuals_nt: np.ndarray  # (K,3)
    sigma_nt: float

    @property
    def std_errors(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance))

    def as_dict(self) -> dict[str, float]:
        return {name: float(v) for name, v in zip(PARAM_NAMES, self.params, strict=True)}


def _jacobian(p: np.ndarray, angles: np.ndarray) -> np.ndarray:
    steps = np.array([1.0, 1.0, 1.0, 1e-4, 1e-4, 1e-4, 1e-4])  # nT, deg
    cols = []
    for i, h in enumerate(steps):
        up, down = p.copy(), p.copy()
        up[i] += h
        down[i] -= h
        cols.append(((table_field_nt(up, angles) - table_field_nt(down, angles)) / (2 * h)).ravel())
    return np.column_stack(cols)


def fit_table_axes(angles_deg, readings_nt, reading_se_nt=None) -> TableFit:
    """Fit PARAM_NAMES to K readings (K,3) at table angles (K,2); FitError when the sequence cannot
    separate them (it must turn both axes, with the field off both axes)."""
    angles = np.atleast_2d(np.asarray(angles_deg, float))
    readings = np.atleast_2d(np.asarray(readings_nt, float))
    k = len(angles)
    if 3 * k <= len(PARAM_NAMES):
        raise FitError(f"table commissioning: {k} orientations; at least 3 needed")
    home = np.argmin(np.abs(angles).sum(axis=1))
    p = np.concatenate([readings[home], np.zeros(4)])
    for _ in range(MAX_ITER):
        r = (readings - table_field_nt(p, angles)).ravel()
        jac = _jacobian(p, angles)
        scale = np.linalg.norm(jac, axis=0)
        scale[scale == 0] = 1.0
        u, s, vt = np.linalg.svd(jac / scale, full_matrices=False)
        if s[-1] < RCOND_SINGULAR * s[0]:
            weak = PARAM_NAMES[int(np.argmax(np.abs(vt[-1])))]
            raise FitError(f"table commissioning: the rotation sequence cannot separate the table's axes "
                           f"({weak} is not identifiable); turn both axes through several angles")
        step = (vt.T @ ((u.T @ r) / s)) / scale
        p = p + step
        if np.all(np.abs(step[:3]) < 1e-6) and np.all(np.abs(step[3:]) < 1e-9):
            break
    residuals = readings - table_field_nt(p, angles)
    dof = max(3 * k - len(PARAM_NAMES), 1)
    sigma2 = float(np.sum(residuals**2) / dof)
    if reading_se_nt is not None:
        sigma2 = max(sigma2, float(np.mean(np.asarray(reading_se_nt, float) ** 2)))
    jac = _jacobian(p, angles)
    scale = np.linalg.norm(jac, axis=0)
    cov_s = np.linalg.pinv((jac / scale).T @ (jac / scale))
    cov_s = 0.5 * (cov_s + cov_s.T)  # exactly symmetric: pinv's rounding is not, and files check it
    return TableFit(p, sigma2 * cov_s / np.outer(scale, scale), residuals, math.sqrt(sigma2))
