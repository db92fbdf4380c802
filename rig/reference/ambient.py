"""The ambient field over a run, from every time the reference magnetometer measured it (at the start, at
each temperature step, at the end): its best estimate at any time, and how uncertain that is.

    model = AmbientModel.fit(measurements)     # [{t, vector_nt, std_error_nt}, ...] (the session's events)
    model.at(times)                            # (N,3) best estimate
    model.draw_error(times, rng)               # (N,3) one draw of its error

A run uses the value in use when each point was taken (rig/reference/sitefield.py); after the run, every
measurement is known, so the fits use the best estimate from all of them (a weighted mean, or a straight
line in time when the measurements show a drift beyond their noise): the noise of any single measurement
no longer sits in the references of the points that used it. Measurements that scatter more than their
standard errors say (an unsteady lab) widen the uncertainty by that excess.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SIGNIFICANT = 3.0  # a drift is fitted when its slope is this many standard errors from zero


@dataclass(frozen=True)
class AmbientModel:
    t0: float
    coef: np.ndarray  # (p,3): value at t0 [, slope per s]
    cov: np.ndarray  # (3,p,p): per axis
    excess_nt: np.ndarray  # (3,): scatter of the measurements beyond their standard errors
    n: int

    @classmethod
    def fit(cls, measurements: list[dict]) -> AmbientModel:
        t = np.array([m["t"] for m in measurements], float)
        y = np.array([m["vector_nt"] for m in measurements], float)
        se = np.maximum(np.array([m["std_error_nt"] for m in measurements], float), 1e-9)
        t0 = float(np.mean(t))
        line = cls._weighted(t - t0, y, se, 2) if len(t) > 2 and np.ptp(t) > 0 else None
        if line is not None and np.any(np.abs(line[0][1]) > SIGNIFICANT * np.sqrt(line[1][:, 1, 1])):
            coef, cov = line
        else:
            coef, cov = cls._weighted(t - t0, y, se, 1)
        x = np.column_stack([np.ones_like(t), t - t0])[:, : len(coef)]
        residual = y - x @ coef
        dof = max(len(t) - len(coef), 1)
        excess = np.sqrt(np.maximum(np.sum(residual**2, axis=0) / dof - np.mean(se**2, axis=0), 0.0))
        return cls(t0, coef, cov, excess, len(t))

    @staticmethod
    def _weighted(dt: np.ndarray, y: np.ndarray, se: np.ndarray, p: int) -> tuple[np.ndarray, np.ndarray]:
        """Per axis weighted least squares of y on [1, dt][:p]: coefficients (p,3), covariances (3,p,p)."""
        x = np.column_stack([np.ones_like(dt), dt])[:, :p]
        coef = np.empty((p, 3))
        cov = np.empty((3, p, p))
        for i in range(3):
            w = 1.0 / se[:, i] ** 2
            cov[i] = np.linalg.pinv(x.T @ (x * w[:, None]))
            coef[:, i] = cov[i] @ (x.T @ (w * y[:, i]))
        return coef, cov

    @property
    def drifting(self) -> bool:
        return len(self.coef) > 1

    def at(self, times) -> np.ndarray:
        x = np.column_stack([np.ones(len(times)), np.asarray(times, float) - self.t0])[:, : len(self.coef)]
        return x @ self.coef

    def draw_error(self, times, rng: np.random.Generator) -> np.ndarray:
        """(N,3): one draw of the estimate's error at `times` (its coefficients' covariance, and any
        excess scatter as a constant offset)."""
        p = len(self.coef)
        x = np.column_stack([np.ones(len(times)), np.asarray(times, float) - self.t0])[:, :p]
        out = np.empty((len(times), 3))
        for i in range(3):
            step = np.linalg.cholesky(self.cov[i] + 1e-30 * np.eye(p)) @ rng.normal(0.0, 1.0, p)
            out[:, i] = x @ step + rng.normal() * self.excess_nt[i]
        return out

    def as_dict(self) -> dict:
        return {"measurements": self.n, "drift": self.drifting,
                "value_nt": [float(v) for v in self.coef[0]],
                **({"drift_nt_per_h": [float(v) * 3600.0 for v in self.coef[1]]} if self.drifting else {}),
                "excess_scatter_nt": [float(v) for v in self.excess_nt]}
