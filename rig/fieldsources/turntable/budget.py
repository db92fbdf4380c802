"""The sources of a turntable station's reference field in a calibration's budget (rig/reference/budget.py
asks the station's field source for them): the table's axes (commissioned), the site field measured at
home and the reference magnetometer that measured it. The field on the table is the same for every DUT."""

from __future__ import annotations

import functools

import numpy as np

from calib.tablefit import site_from_home, table_field_nt
from calib.uncertainty import Draw, Source


class TableChain:
    """The sources of a turntable station (the field on the table is the same for every DUT)."""

    def __init__(self, run, ds):
        self.run = run
        self.source = run.station.field_source
        recorded = [run.point_refs.get(p, {}).get("table_params") for p in ds.columns["point"]]
        fallback = next((r for r in recorded if r is not None), None)
        if fallback is None:  # a session from before points stored their reference
            fallback = list(self.source.reference(run.site[0]["vector_nt"] if run.site else None).params)
        self.params = np.array([fallback if r is None else r for r in recorded], float)
        targets = {pid: p["target"] for pid, p in run.points.items()}
        self.angles = np.array([[targets[p]["az_deg"], targets[p]["el_deg"]] for p in ds.columns["point"]])
        self.home = None if not run.site else np.asarray(run.site[0]["vector_nt"], float)

    def _change(self, shift) -> np.ndarray:
        """(N,3): the field change when every point's parameters move by shift(params)."""
        out = np.empty((len(self.params), 3))
        for key in np.unique(self.params, axis=0):
            rows = np.all(self.params == key, axis=1)
            out[rows] = table_field_nt(shift(key), self.angles[rows]) - table_field_nt(key, self.angles[rows])
        return out

    def sources(self, notes: list[str]) -> list[Source | None]:
        com = self.source.commissioned
        out: list[Source | None] = []
        if com is not None:
            out.append(Source("table axes", self._axes_draw, f"commissioned {com.record.created_utc}"))
        else:
            notes.append("turntable not commissioned: its axes are taken as drawn (rig commission measures "
                         "them)")
        if self.home is None:
            notes.append("site field as stated in the station: its uncertainty is not known (0 taken)")
            return out
        out.append(Source("site field", self._site_draw, "measured at the start"))
        if self.run.reference_cal is not None:
            out.append(Source("reference magnetometer", self._reference_draw,
                              "its calibration's stated uncertainty"))
        return out

    @functools.cached_property
    def _axes_cholesky(self) -> np.ndarray:
        return np.linalg.cholesky(self.source.commissioned.covariance)

    def _axes_draw(self, rng: np.random.Generator) -> Draw:
        step = self._axes_cholesky @ rng.normal(0.0, 1.0, 7)
        return Draw(ref_nt=self._change(lambda p: _keep_site(p, p + step)))

    def _site_draw(self, rng: np.random.Generator) -> Draw:
        home = self.home + rng.normal(0.0, 1.0, 3) * np.asarray(self.run.site[0]["std_error_nt"], float)
        return Draw(ref_nt=self._change(lambda p: _with_home(p, home)))

    def _reference_draw(self, rng: np.random.Generator) -> Draw:
        t, d = self.run.reference_transform(rng)
        home = t @ self.home + d
        return Draw(ref_nt=self._change(lambda p: _with_home(p, home)))


def _keep_site(old: np.ndarray, new: np.ndarray) -> np.ndarray:
    """New axes, with the site field still what the reference read at home."""
    return _with_home(new, table_field_nt(old, [[0.0, 0.0]])[0])


def _with_home(params: np.ndarray, home_nt: np.ndarray) -> np.ndarray:
    out = params.copy()
    out[:3] = site_from_home(params, home_nt)
    return out
