"""Residual statistics of a calibration on a dataset: overall, per axis and per temperature step."""

from __future__ import annotations

import numpy as np

from calib.dataset import Dataset

AXES = "xyz"
STEP_GAP_C = 1.0  # temperatures further apart than this belong to different steps


def temperature_steps(temp_c: np.ndarray) -> np.ndarray:
    """Label each sample with its temperature step: sorted temperatures split where the gap > STEP_GAP_C."""
    order = np.argsort(temp_c, kind="stable")
    t_sorted = temp_c[order]
    step_sorted = np.concatenate([[0], np.cumsum(np.diff(t_sorted) > STEP_GAP_C)])
    labels = np.empty(temp_c.shape[0], dtype=object)
    for step in np.unique(step_sorted):
        members = order[step_sorted == step]
        labels[members] = f"{np.mean(temp_c[members]):.1f}C"
    return labels


def groups_of(ds: Dataset) -> np.ndarray | None:
    if ds.group is not None:
        return np.asarray(ds.group)
    if ds.temp_c is not None:
        return temperature_steps(np.asarray(ds.temp_c, float))
    return None


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if x.size else float("nan")


def known_norm(ds: Dataset) -> np.ndarray | None:
    """|B| per sample when known: the given magnitude, else the norm of the reference vector."""
    if ds.ref_norm_nt is not None:
        return np.asarray(ds.ref_norm_nt, float)
    if ds.ref_nt is not None:
        return np.linalg.norm(ds.ref_nt, axis=1)
    return None


def residual_stats(
    ds: Dataset, field_nt: np.ndarray, *, vector: bool, used: np.ndarray | None = None, norm_nt=None
) -> dict:
    """RMS before (raw h against the reference) and after calibration, on the rows marked `used`.

    vector=True compares field vectors with ref_nt (T24, P12); otherwise magnitudes with norm_nt
    (a constant or per-sample array; default: the known |B| of the dataset).
    """
    used = np.ones(len(ds), bool) if used is None else used
    if vector:
        after = field_nt - ds.ref_nt
        before = ds.h_nt - ds.ref_nt
    else:
        norm = known_norm(ds) if norm_nt is None else norm_nt
        after = np.linalg.norm(field_nt, axis=1) - norm
        before = np.linalg.norm(ds.h_nt, axis=1) - norm
    stats: dict = {
        "rms_before_nt": _rms(before[used]),
        "rms_after_nt": _rms(after[used]),
    }
    if vector:
        stats["per_axis"] = {
            a: {"rms_before_nt": _rms(before[used, i]), "rms_after_nt": _rms(after[used, i])}
            for i, a in enumerate(AXES)
        }
    else:
        mag = np.linalg.norm(field_nt[used], axis=1)
        stats["norm_spread_pct"] = float(100 * np.std(mag) / np.mean(mag))
    groups = groups_of(ds)
    if groups is not None:
        per_group = {}
        for label in _ordered_unique(groups):
            rows = (groups == label) & used
            entry = {
                "n": int(rows.sum()),
                "rms_before_nt": _rms(before[rows]),
                "rms_after_nt": _rms(after[rows]),
            }
            if ds.temp_c is not None and rows.any():
                entry["temp_c"] = float(np.mean(ds.temp_c[rows]))
            per_group[_label_text(label)] = entry
        stats["per_group"] = per_group
    return stats


def _label_text(label) -> str:
    """Group labels read from a CSV arrive as floats: 3.0 prints as '3'."""
    if isinstance(label, float) and label.is_integer():
        return str(int(label))
    return str(label)


def _ordered_unique(labels: np.ndarray) -> list:
    seen: dict = {}
    for label in labels.tolist():
        seen.setdefault(label, None)
    return list(seen)
