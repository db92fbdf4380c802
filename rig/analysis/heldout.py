"""The numbers behind the report: errors before/after, held-out model comparison, coverage, steps.

Pure functions on a calib Dataset and fitted calibrations; the fit itself is passed in (`fit(ds, model)`),
so this module knows nothing about files and is tested with any fitting function.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from calib.models.registry import REGISTRY, VECTOR_MODELS  # VECTOR_MODELS: outputs in the reference frame
from calib.stats.directions import (  # probes: the plans' spiral
    fibonacci_directions,
    nearest_deg,
    unit_vectors,
)
from rig.core.errors import FitError

STEP_LABEL = re.compile(r"^T(\d+)")  # plan step ids: T03-O07 = temperature 3 x orientation 7
COVERAGE_PROBES = 200  # directions, evenly spread, at which coverage is checked
COVERAGE_GAP_DEG = 40.0  # no sample this close: a gap (the full campaign's 24 directions leave <= 36 deg)
N_FOLDS = 5


def rms(x: np.ndarray) -> float:
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x**2))) if x.size else float("nan")


def reference_norm_nt(ds) -> np.ndarray | None:
    """|B| of the reference: from the vector when known, else the known magnitude."""
    if ds.ref_nt is not None:
        return np.linalg.norm(ds.ref_nt, axis=1)
    if ds.ref_norm_nt is not None:
        return np.asarray(ds.ref_norm_nt, dtype=float)
    return None


def models_for(ds) -> list[str]:
    """The models this data can fit (calib's registry): vector models need the reference vector, some
    models temperatures; the others need |B| only."""
    has_reference = {True: ds.ref_nt is not None, False: ds.ref_nt is not None or ds.ref_norm_nt is not None}
    return [m for m, spec in REGISTRY.items()
            if has_reference[spec.vector] and (ds.temp_c is not None or not spec.needs_temperature)]


@dataclass
class Errors:
    """Per-row errors in nT. Vector errors are None without a reference vector."""

    vector_before: np.ndarray | None
    vector_after: np.ndarray | None
    norm_before: np.ndarray
    norm_after: np.ndarray
    field_after: np.ndarray


def errors(ds, cal) -> Errors:
    """Errors of the raw readings (taken as the field) and of the calibrated field, against the reference."""
    field_after = cal.apply(ds.h_nt, ds.temp_c)
    ref_norm = reference_norm_nt(ds)
    norm_before = np.linalg.norm(ds.h_nt, axis=1) - ref_norm
    norm_after = np.linalg.norm(field_after, axis=1) - ref_norm
    if ds.ref_nt is None:
        return Errors(None, None, norm_before, norm_after, field_after)
    vector_after = field_after - ds.ref_nt if cal.model in VECTOR_MODELS else None
    return Errors(ds.h_nt - ds.ref_nt, vector_after, norm_before, norm_after, field_after)


@dataclass
class ModelScore:
    """Fit and held-out RMS of one model (nT); NaN where not defined. `note` says why a value is missing."""

    model: str
    fit_vector_rms: float = float("nan")
    fit_norm_rms: float = float("nan")
    heldout_vector_rms: float = float("nan")
    heldout_norm_rms: float = float("nan")
    folds: int = 0
    note: str = ""


def fold_of_each_row(
    ds, labels: np.ndarray | None = None, k: int = N_FOLDS, seed: int = 0
) -> tuple[np.ndarray, str]:
    """Fold index per row, with whole points (rows sharing a label) kept together so held-out points are
    truly unseen. Without labels (or too few) rows are dealt in contiguous blocks, which keeps the
    neighbouring samples of one point together as far as the file order allows.
    """
    n = len(ds)
    rng = np.random.default_rng(seed)
    if labels is not None:
        names, inverse = np.unique(np.asarray(labels).astype(str), return_inverse=True)
        if len(names) >= 2 * k:
            fold_of_label = rng.permutation(len(names)) % k
            return fold_of_label[inverse], f"{k}-fold over {len(names)} points"
    blocks = np.arange(n) * (4 * k) // max(n, 1)  # 4k contiguous blocks, k folds
    fold_of_block = rng.permutation(4 * k) % k
    return fold_of_block[blocks], f"{k}-fold over {4 * k} contiguous blocks of rows"


def cross_validate(
    ds, model: str, fit: Callable, folds: np.ndarray, full_fit=None, exclude: np.ndarray | None = None
) -> ModelScore:
    """Fit on k-1 folds, score on the held-out fold; the RMS is over all held-out rows of all folds.

    `exclude` marks rows left out of every score (the outliers of the calibration shown), so all models
    are scored on the same rows.
    """
    score = ModelScore(model)
    scored = np.ones(len(ds), bool) if exclude is None else ~np.asarray(exclude, bool)
    if full_fit is not None:
        e = errors(ds, full_fit)
        keep = kept_rows(full_fit, len(ds)) & scored
        score.fit_norm_rms = rms(e.norm_after[keep])
        if e.vector_after is not None:
            score.fit_vector_rms = rms(e.vector_after[keep])
    held_vec, held_norm, failures = [], [], []
    for f in np.unique(folds):
        test = folds == f
        if not (test & scored).any():
            continue
        try:
            cal = fit(ds.subset(~test), model)
        except FitError as err:
            failures.append(str(err))
            continue
        e = errors(ds.subset(test & scored), cal)
        held_norm.append(e.norm_after)
        if e.vector_after is not None:
            held_vec.append(e.vector_after)
    score.folds = len(held_norm)
    if held_norm:
        score.heldout_norm_rms = rms(np.concatenate(held_norm))
    if held_vec:
        score.heldout_vector_rms = rms(np.concatenate(held_vec))
    if failures:
        score.note = f"{len(failures)} fold(s) could not be fitted: {failures[0]}"
    return score


def kept_rows(cal, n: int) -> np.ndarray:
    """Rows the fit kept (not flagged as outliers)."""
    if cal.outliers is None or len(cal.outliers) != n:
        return np.ones(n, bool)
    return ~np.asarray(cal.outliers, bool)


def outlier_rows(cal, err: Errors) -> np.ndarray:
    """Outliers of the calibration shown: those its robust fit flagged, or, for a calibration read from a
    file (which keeps no flags), rows whose residual lies beyond the robust fit's own flag threshold."""
    if cal.outliers is not None and len(cal.outliers) == len(err.norm_after):
        return np.asarray(cal.outliers, bool)
    from calib.stats.robust import FLAG_D, robust_scale, row_distance

    res = err.vector_after if err.vector_after is not None else err.norm_after[:, None]
    return row_distance(res, robust_scale(res)) > FLAG_D[res.shape[1]]


# ---------------------------------------------------------------------------------------------- steps


def step_of_each_row(ds) -> np.ndarray:
    """Temperature-step number per row: the dataset's group labels (a session's temperature index, or plan
    ids like T03-O07) when present, else temperature steps found from gaps in the temperatures."""
    if ds.group is not None:
        labels = np.asarray(ds.group)
        if np.issubdtype(labels.dtype, np.integer):
            return labels.astype(int)
        found = [STEP_LABEL.match(str(g)) for g in labels]
        if all(found):
            return np.array([int(m.group(1)) for m in found])
    if ds.temp_c is None:
        return np.ones(len(ds), int)
    from calib.stats.residuals import temperature_steps

    steps, _ = temperature_steps(ds.temp_c)  # numbered from the coldest
    return steps + 1


@dataclass
class StepRow:
    step: int
    temp_c: float
    samples: int
    rms_before_nt: float
    rms_after_nt: float
    outliers: int
    extra: dict = field(default_factory=dict)  # settle time, status... from the session when known


def step_table(ds, flagged: np.ndarray, err: Errors) -> list[StepRow]:
    """Samples, mean temperature, residual RMS (vector when known, else |B|) and outliers per step."""
    steps = step_of_each_row(ds)
    before = err.vector_before if err.vector_after is not None else err.norm_before
    after = err.vector_after if err.vector_after is not None else err.norm_after
    rows = []
    for s in np.unique(steps):
        m = steps == s
        temp = float(np.mean(ds.temp_c[m])) if ds.temp_c is not None else float("nan")
        rows.append(
            StepRow(
                int(s), temp, int(m.sum()), rms(before[m]), rms(after[m & ~flagged]), int((m & flagged).sum())
            )
        )
    return rows


# ---------------------------------------------------------------------------------------------- coverage


def nearest_sample_deg(probe_unit: np.ndarray, direction_nt: np.ndarray) -> np.ndarray:
    """Angle (deg) from each probe unit vector (M, 3) to the nearest sample direction."""
    return nearest_deg(np.unique(np.round(unit_vectors(direction_nt), 3), axis=0), probe_unit)


def coverage_gaps(
    direction_nt: np.ndarray, max_gap_deg: float = COVERAGE_GAP_DEG, probes: int = COVERAGE_PROBES
) -> list[tuple[float, float, float]]:
    """Probe directions, spread evenly over the sphere, with no sample within `max_gap_deg`:
    (azimuth_deg, elevation_deg, nearest_deg) each."""
    p = fibonacci_directions(probes)
    nearest_deg = nearest_sample_deg(p, direction_nt)
    gaps = nearest_deg > max_gap_deg
    az = np.degrees(np.arctan2(p[:, 1], p[:, 0]))
    el = np.degrees(np.arcsin(p[:, 2]))
    return [
        (float(a), float(e), float(d)) for a, e, d in zip(az[gaps], el[gaps], nearest_deg[gaps], strict=True)
    ]


def systematic_error_by_point(
    group: np.ndarray | None, direction_nt: np.ndarray, residual_nt: np.ndarray, keep: np.ndarray
) -> tuple[np.ndarray, np.ndarray, bool]:
    """Mean field direction and |mean residual| of each point (rows sharing a group label), over the
    rows marked `keep`: the noise averages out and what remains is the error the model leaves at that
    direction. Without labels (or one sample per point): each kept row with its own |residual|.
    The flag says which of the two it is (True: per point)."""
    residual_nt = np.asarray(residual_nt, dtype=float).reshape(len(residual_nt), -1)
    keep = np.asarray(keep, bool)
    if group is not None:
        labels, inverse = np.unique(np.asarray(group).astype(str)[keep], return_inverse=True)
    if group is None or len(labels) * 2 > keep.sum():
        return direction_nt[keep], np.linalg.norm(residual_nt[keep], axis=1), False
    counts = np.bincount(inverse)[:, None]
    mean_dir = np.column_stack([np.bincount(inverse, c) for c in direction_nt[keep].T]) / counts
    mean_res = np.column_stack([np.bincount(inverse, c) for c in residual_nt[keep].T]) / counts
    return mean_dir, np.linalg.norm(mean_res, axis=1), True
