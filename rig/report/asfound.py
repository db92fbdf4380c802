"""As found: the DUT's raw reading against the reference field at every calibration point, before any
adjustment (ISO/IEC 17025:2017 7.8.4.1 d), each error with its expanded uncertainty.

    rows, notes = as_found(record)       # record: rig/report/certificate_record.py

At a point (one field target at one temperature) the error is e = mean(h - B_ref) over the point's
samples, per axis: h the raw reading in nT as the device gave it (no calibration, no correction), B_ref
the reference field the run made for it, with the run's best ambient estimate (as the fit used it). Its
standard uncertainty has two parts:
- the reference field's at the point: every source of the station's reference chain (the field source's
  `budget_chain`: coil matrix, reference magnetometer, ambient, position, geometry, loops...), each one's
  covariance through its sensitivity averaged over the point's samples;
- the reading's scatter: the pooled standard deviation of h - B_ref about the point means, / sqrt(n).
U = k u per axis, k = t_95.45 of the effective degrees of freedom (Welch-Satterthwaite, GUM G.4, over the
parts estimated from few readings: the scatter's, the ambient's).
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass

import numpy as np

from calib.stats.student import coverage_factor, effective_dof
from calib.uncertainty.rowgroups import RowGroups
from rig.report.html import ItemList, Section, Table


@dataclass(frozen=True)
class AsFound:
    point: str
    temp_c: float
    reference_nt: np.ndarray  # (3,) the mean reference field
    error_nt: np.ndarray  # (3,) mean(h - B_ref)
    expanded_nt: np.ndarray  # (3,) U = k u
    k: np.ndarray  # (3,)
    samples: int


def _point_mean(a, rows: np.ndarray) -> np.ndarray:
    """(3, Q): a source's reference sensitivity averaged over `rows`."""
    if isinstance(a, RowGroups):
        return a.per_group[a.index[rows]].mean(axis=0)
    return np.asarray(a, float)[rows].mean(axis=0)


def _reference_parts(sources, ds, points: list[np.ndarray]) -> tuple[np.ndarray, list[tuple]]:
    """(the reference field's variance per point and axis (P,3), [(variance (P,3), dof)] of the parts
    estimated from few readings)."""
    total = np.zeros((len(points), 3))
    estimated = []
    for source in sources:
        a_ref, _ = source.sensitivities(ds)
        if a_ref is None:
            continue  # it moves the temperature alone: a condition of the point, not its field
        sigma = np.atleast_2d(np.asarray(source.covariance, float))
        means = np.array([_point_mean(a_ref, rows) for rows in points])  # (P,3,Q)
        total += np.einsum("piq,qr,pir->pi", means, sigma, means)
        for part in source.estimated:
            picked = means[:, :, part.index]
            estimated.append((np.einsum("piq,q->pi", picked**2, np.asarray(part.variance, float)), part.dof))
    return total, estimated


def as_found(record) -> tuple[list[AsFound], list[str]]:
    """Every calibration point's as-found error with its U; notes from the reference chain's sources."""
    run = record.run
    ds, _ = run.refined(record.ds)
    notes: list[str] = []
    chain = run.station.field_source.budget_chain(run, record.dut, ds)
    # issue 46's budget adds a list of the values stated without an uncertainty (the calibration file's
    # uncertainty.missing refuses the certificate before this); a budget before it takes the notes alone
    takes_missing = "missing" in inspect.signature(chain.sources).parameters
    sources = chain.sources(notes, []) if takes_missing else chain.sources(notes)
    ids = np.asarray(ds.columns["point"])
    order = list(dict.fromkeys(ids.tolist()))  # the points in the order taken
    points = [np.flatnonzero(ids == p) for p in order]
    diff = np.asarray(ds.h_nt, float) - np.asarray(ds.ref_nt, float)
    means = np.array([diff[rows].mean(axis=0) for rows in points])
    counts = np.array([len(rows) for rows in points])
    scatter_dof = len(diff) - len(points)
    scatter = np.zeros(3)
    if scatter_dof > 0:
        spread = np.concatenate([diff[rows] - diff[rows].mean(axis=0) for rows in points])
        scatter = np.sum(spread**2, axis=0) / scatter_dof
    else:
        notes.append("one sample per point: the reading's scatter cannot be estimated (not in U)")
    reference, estimated = _reference_parts(sources, ds, points)
    reading = scatter[None, :] / counts[:, None]
    total = reference + reading
    rows = []
    for i, point in enumerate(order):
        parts = [[(v[i, axis], dof) for v, dof in estimated] + [(reading[i, axis], scatter_dof)]
                 for axis in range(3)]
        k = np.array([coverage_factor(effective_dof(total[i, axis], parts[axis])) for axis in range(3)])
        rows.append(AsFound(str(point), float(np.mean(ds.temp_c[points[i]])),
                            np.asarray(ds.ref_nt, float)[points[i]].mean(axis=0), means[i],
                            k * np.sqrt(total[i]), k, int(counts[i])))
    return rows, notes


def _vector(v, spec: str = "+.1f") -> str:
    return "(" + ", ".join(format(float(x), spec) for x in v) + ")"


def as_found_section(rows: list[AsFound], notes: list[str], probability: float) -> Section:
    table = [[a.point, f"{a.temp_c:.2f}", _vector(a.reference_nt, ".1f"), _vector(a.error_nt),
              _vector(a.expanded_nt, ".3g"), _vector(a.k, ".3g"), str(a.samples)] for a in rows]
    worst = max(rows, key=lambda a: float(np.max(np.abs(a.error_nt))), default=None)
    said = [] if worst is None else [
        f"Largest error component: {float(np.max(np.abs(worst.error_nt))):.1f} nT at {worst.point}."]
    return Section("As found", [
        "Before adjustment: the raw reading h (nT, as the device gave it) against the reference field at "
        "every calibration point, error = mean(h - B_ref) per axis (x, y, z: the frames of Measurand), with "
        f"its expanded uncertainty U = k u ({probability * 100:.2f} %): the reference field's from every "
        "source of the chain, and the reading's scatter over the point's samples.", *said,
        ItemList([f"Not in U: {n}" for n in notes], empty_text=""),
        Table(["point", "T (degC)", "B_ref (nT)", "h - B_ref (nT)", "U (nT)", "k", "samples"], table,
              caption="As found")])
