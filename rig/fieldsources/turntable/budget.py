"""The input quantities of a turntable station's reference field in a calibration's budget
(rig/budget/run_inputs.py asks the station's field source for them): the table's axes (commissioned), the
site field measured at home over the run and the reference magnetometer that measured it, and the lab
field's gradient between the reference's place and the DUT's as the table turns. Each moves the field at
every sample through its sensitivity (N,3,Q), taken by central differences of
calib.commissioning.tablefit.table_field_nt (exact: the field is linear in the site field and in the home
reading)."""

from __future__ import annotations

import dataclasses

import numpy as np

from calib.commissioning.tablefit import site_from_home, table_field_nt
from calib.uncertainty.propagation import InputSource
from drivers.turntable import rotation_deg
from rig.fieldsources.ambientlines import ambient_source, stated_gradient_source

AXIS_STEPS = np.array([1.0, 1.0, 1.0, 1e-3, 1e-3, 1e-3, 1e-3])  # nT, deg: central-difference steps
HOME_STEP_NT = 1.0


def table_rows(run, ds) -> tuple[np.ndarray, np.ndarray]:
    """(params (N,7), angles (N,2) az, el deg): each sample's table as its point was taken with, and where
    the table stood."""
    recorded = [run.point_refs.get(p, {}).get("table_params") for p in ds.columns["point"]]
    fallback = next((r for r in recorded if r is not None), None)
    if fallback is None:  # a session from before points stored their reference
        fallback = list(run.station.field_source.reference(run.site[0]["vector_nt"] if run.site else None)
                        .params)
    params = np.array([fallback if r is None else r for r in recorded], float)
    targets = {pid: p["target"] for pid, p in run.points.items()}
    angles = np.array([[targets[p]["az_deg"], targets[p]["el_deg"]] for p in ds.columns["point"]], float)
    return params, angles


def home_readings(params: np.ndarray) -> np.ndarray:
    """(N,3): what the reference read at home for each sample's table (the site field it was made with)."""
    out = np.empty((len(params), 3))
    for key in np.unique(params, axis=0):
        out[np.all(params == key, axis=1)] = table_field_nt(key, [[0.0, 0.0]])[0]
    return out


def home_sensitivity(params: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """(N,3,3): how each sample's field moves with the home reading its table was made from."""
    return _sensitivity(params, angles, lambda p, q: _with_home(p, table_field_nt(p, [[0.0, 0.0]])[0] + q),
                        np.full(3, HOME_STEP_NT))


class TableChain:
    """The sources of a turntable station for one DUT: every one but the gradient is the same for all."""

    def __init__(self, run, dut: str, ds):
        self.run = run
        self.source = run.station.field_source
        self.times = np.asarray(ds.columns["t"], float)
        self.params, self.angles = table_rows(run, ds)
        position = run.station.dut(dut).position_mm
        self.position_m = np.zeros(3) if position is None else np.asarray(position, float) / 1000.0

    def sources(self, notes: list[str]) -> list[InputSource]:
        com = self.source.commissioned
        out: list[InputSource] = []
        if com is not None:
            by_axes = _sensitivity(self.params, self.angles, lambda p, q: _keep_site(p, p + q), AXIS_STEPS)
            out.append(InputSource("table axes", com.covariance, ref_nt=by_axes, shared="table axes",
                                   origin=f"commissioned {com.record.created_utc} ({com.path.name}): its "
                                   "covariance"))
        else:
            notes.append("turntable not commissioned: its axes are taken as drawn (rig commission measures "
                         "them)")
        model = self.run.ambient
        if model is None:
            notes.append("site field as stated in the station: its uncertainty is not known (0 taken)")
            return out
        by_home = home_sensitivity(self.params, self.angles)
        out.append(ambient_source(model, self.times, "site field", by=by_home))
        for source in self.run.reference_sources(model.at(self.times), notes):
            a_home = np.asarray(source.ref_nt, float)  # (N,3,Q): the home reading's change
            out.append(dataclasses.replace(source, ref_nt=np.einsum("nij,njq->niq", by_home, a_home)))
        return out + self._gradient(by_home, notes)

    def _gradient(self, by_home: np.ndarray, notes: list[str]) -> list[InputSource]:
        """The reference read the site field at home at its own place on the table; the DUT sits elsewhere
        on it, and turning the table carries it through the lab's gradient: at each sample it is
        R(az, el) r_DUT - r_ref from where the field was measured (lab frame; the home reading's frame
        taken as the lab's, within the table's small tilts)."""
        reference_m = self.run.reference_position_mm() / 1000.0
        poses, pose = np.unique(self.angles, axis=0, return_inverse=True)  # a point's samples share one
        turned = np.array([rotation_deg(*a) @ self.position_m for a in poses])
        offsets = turned[pose.ravel()] - reference_m
        if not np.any(offsets):
            return []
        bound = self.source.ambient_gradient_nt_per_m
        if bound is None:
            far = float(np.max(np.linalg.norm(offsets, axis=1))) * 1000.0
            notes.append(f"ambient gradient over up to {far:.0f} mm between where the reference measured the "
                         "site field and the DUT as the table turns: not stated (field_source."
                         "ambient_gradient_nt_per_m), not in the budget")
            return []
        return [stated_gradient_source(offsets, bound, by=by_home)]


def _sensitivity(params: np.ndarray, angles: np.ndarray, shift_by, steps: np.ndarray) -> np.ndarray:
    """(N,3,Q): d field / d q_k by central differences, shift_by(params, q) giving the moved params."""
    out = np.empty((len(params), 3, len(steps)))
    for k, step in enumerate(steps):
        q = np.zeros(len(steps))
        q[k] = step
        out[:, :, k] = (_change(params, angles, lambda p, q=q: shift_by(p, q))
                        - _change(params, angles, lambda p, q=q: shift_by(p, -q))) / (2 * step)
    return out


def _change(params: np.ndarray, angles: np.ndarray, shift) -> np.ndarray:
    """(N,3): the field change when every sample's parameters move by shift(params)."""
    out = np.empty((len(params), 3))
    for key in np.unique(params, axis=0):
        rows = np.all(params == key, axis=1)
        out[rows] = table_field_nt(shift(key), angles[rows]) - table_field_nt(key, angles[rows])
    return out


def _keep_site(old: np.ndarray, new: np.ndarray) -> np.ndarray:
    """New axes, with the site field still what the reference read at home."""
    return _with_home(new, table_field_nt(old, [[0.0, 0.0]])[0])


def _with_home(params: np.ndarray, home_nt: np.ndarray) -> np.ndarray:
    out = params.copy()
    out[:3] = site_from_home(params, home_nt)
    return out
