"""The ambient field over a run, from every time the reference magnetometer measured it (at the start, at
each temperature step, at the end): its best estimate at any time, and how uncertain that is.

    model = AmbientModel.fit(measurements)     # [{t, vector_nt, std_error_nt}, ...] (the session's events)
    model.at(times)                            # (N,3) best estimate

A run uses the value in use when each point was taken (rig/reference/sitefield.py); after the run, every
measurement is known, so the fits use the best estimate from all of them (a weighted mean, or a straight
line in time when the measurements show a drift beyond their noise): the noise of any single measurement
no longer sits in the references of the points that used it. Measurements that scatter beyond their
standard errors (an unsteady lab: the chamber's heater and compressor fields, which follow the
temperature step, things moved in the building) are not noise about a line: there each epoch's estimate
is its own measurement (the one at the start of its temperature step), carried on by the line's drift,
and its uncertainty that measurement's standard error and the excess scatter, as the lab may move that
much again within the epoch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SIGNIFICANT = 3.0  # a drift is fitted when its slope is this many standard errors from zero; the scatter
# is the lab's own when its chi2 per degree of freedom is this many of its standard deviations above 1


@dataclass(frozen=True)
class AmbientModel:
    t0: float
    coef: np.ndarray  # (p,3): value at t0 [, slope per s]
    cov: np.ndarray  # (3,p,p): per axis
    excess_nt: np.ndarray  # (3,): scatter of the measurements beyond their standard errors
    n: int
    measured_t: np.ndarray  # (n,) when the measurements were taken, in order: each begins an epoch
    # where that scatter is significant, each epoch's own measurement: values and standard errors (n,3);
    # None: the line (or mean) is the estimate everywhere
    anchors: np.ndarray | None = None
    anchor_se: np.ndarray | None = None

    @classmethod
    def fit(cls, measurements: list[dict]) -> AmbientModel:
        t = np.array([m["t"] for m in measurements], float)
        y = np.array([m["vector_nt"] for m in measurements], float)
        se = np.maximum(np.array([m["std_error_nt"] for m in measurements], float), 1e-9)
        t0 = float(np.mean(t))
        coef, cov = cls._weighted(t - t0, y, se, 1)
        if len(t) > 2 and np.ptp(t) > 0:
            line = cls._weighted(t - t0, y, se, 2)
            # the slope against its scatter, the lab's moving included (Birge), not the readings' noise alone
            widen = np.maximum(cls._chi2(t - t0, y, se, line[0]), 1.0)
            if np.any(np.abs(line[0][1]) > SIGNIFICANT * np.sqrt(line[1][:, 1, 1] * widen)):
                coef, cov = line
        x = np.column_stack([np.ones_like(t), t - t0])[:, : len(coef)]
        residual = y - x @ coef
        dof = max(len(t) - len(coef), 1)
        excess = np.sqrt(np.maximum(np.sum(residual**2, axis=0) / dof - np.mean(se**2, axis=0), 0.0))
        chi2 = cls._chi2(t - t0, y, se, coef)
        order = np.argsort(t, kind="stable")
        if len(t) < 2 or not np.any(chi2 > 1.0 + SIGNIFICANT * np.sqrt(2.0 / dof)):
            return cls(t0, coef, cov, excess, len(t), t[order])
        widened = cov * np.maximum(chi2, 1.0)[:, None, None]
        return cls(t0, coef, widened, excess, len(t), t[order], y[order], se[order])

    @staticmethod
    def _chi2(dt: np.ndarray, y: np.ndarray, se: np.ndarray, coef: np.ndarray) -> np.ndarray:
        """(3,): chi2 per degree of freedom of the measurements about `coef`, per axis."""
        x = np.column_stack([np.ones_like(dt), dt])[:, : len(coef)]
        return np.sum(((y - x @ coef) / se) ** 2, axis=0) / max(len(dt) - len(coef), 1)

    @property
    def anchored(self) -> bool:
        return self.anchors is not None

    def epochs(self, times) -> np.ndarray:
        """(N,): the epoch of every time (the last measurement before it; the first before any)."""
        return np.clip(np.searchsorted(self.measured_t, np.asarray(times, float), side="right") - 1, 0, None)

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
        times = np.asarray(times, float)
        if self.anchored:
            e = self.epochs(times)
            slope = self.coef[1] if self.drifting else np.zeros(3)
            return self.anchors[e] + (times - self.measured_t[e])[:, None] * slope
        x = np.column_stack([np.ones(len(times)), times - self.t0])[:, : len(self.coef)]
        return x @ self.coef

    def as_dict(self) -> dict:
        return {"measurements": self.n, "drift": self.drifting,
                "value_nt": [float(v) for v in self.coef[0]],
                **({"drift_nt_per_h": [float(v) * 3600.0 for v in self.coef[1]]} if self.drifting else {}),
                "excess_scatter_nt": [float(v) for v in self.excess_nt],
                **({"per_epoch": True} if self.anchored else {})}
