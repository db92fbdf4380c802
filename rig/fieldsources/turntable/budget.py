"""The input quantities of a turntable station's reference field in a calibration's budget
(rig/reference/budget.py asks the station's field source for them): the table's axes (commissioned), the
site field measured at home and the reference magnetometer that measured it. The field on the table is the
same for every DUT, so every source is shared by the campaign's DUTs. Each moves the field at every sample
through its sensitivity (N,3,Q), taken by central differences of calib.tablefit.table_field_nt."""

from __future__ import annotations

import dataclasses

import numpy as np

from calib.propagation import InputSource
from calib.tablefit import site_from_home, table_field_nt

AXIS_STEPS = np.array([1.0, 1.0, 1.0, 1e-3, 1e-3, 1e-3, 1e-3])  # nT, deg: central-difference steps
HOME_STEP_NT = 1.0


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

    def _sensitivity(self, shift_by, steps: np.ndarray) -> np.ndarray:
        """(N,3,Q): d field / d q_k by central differences, shift_by(params, q) giving the moved params."""
        out = np.empty((len(self.params), 3, len(steps)))
        for k, step in enumerate(steps):
            q = np.zeros(len(steps))
            q[k] = step
            out[:, :, k] = (self._change(lambda p, q=q: shift_by(p, q))
                            - self._change(lambda p, q=q: shift_by(p, -q))) / (2 * step)
        return out

    def sources(self, notes: list[str]) -> list[InputSource]:
        com = self.source.commissioned
        out: list[InputSource] = []
        if com is not None:
            by_axes = self._sensitivity(lambda p, q: _keep_site(p, p + q), AXIS_STEPS)
            out.append(InputSource("table axes", com.covariance, ref_nt=by_axes, shared="table axes",
                                   origin=f"commissioned {com.record.created_utc} ({com.path.name}): its "
                                   "covariance"))
        else:
            notes.append("turntable not commissioned: its axes are taken as drawn (rig commission measures "
                         "them)")
        if self.home is None:
            notes.append("site field as stated in the station: its uncertainty is not known (0 taken)")
            return out
        by_home = self._sensitivity(lambda p, q: _with_home(p, self.home + q), np.full(3, HOME_STEP_NT))
        se = np.asarray(self.run.site[0]["std_error_nt"], float)
        out.append(InputSource("site field", np.diag(se**2), ref_nt=by_home, shared="site field",
                               origin="measured at home at the start"))
        for source in self.run.reference_sources(np.broadcast_to(self.home, (len(self.params), 3)), notes):
            a_home = np.asarray(source.ref_nt, float)  # (N,3,Q): the home reading's change
            out.append(dataclasses.replace(source, ref_nt=np.einsum("nij,njq->niq", by_home, a_home)))
        return out


def _keep_site(old: np.ndarray, new: np.ndarray) -> np.ndarray:
    """New axes, with the site field still what the reference read at home."""
    return _with_home(new, table_field_nt(old, [[0.0, 0.0]])[0])


def _with_home(params: np.ndarray, home_nt: np.ndarray) -> np.ndarray:
    out = params.copy()
    out[:3] = site_from_home(params, home_nt)
    return out
