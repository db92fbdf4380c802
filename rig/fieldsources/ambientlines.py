"""The lab field where a field source's references were made, as lines of the budget for every kind of
field source: the run's model of its ambient (rig/reference/ambient.py: the coils' ambient, a table's site
field) and a stated bound on its gradient between the reference magnetometer and a DUT."""

from __future__ import annotations

import numpy as np

from calib.uncertainty.propagation import Estimated, InputSource


def ambient_source(model, times, name: str, by=None) -> InputSource:
    """The run's estimate of the ambient (a turntable's: its site field) as a line of the budget: the
    model's coefficients (value at t0 [, slope per s]) per axis, and any excess scatter of its measurements
    (the lab's field moving by more than their noise between them: steps, a chamber's heater and
    compressor) as an offset of its own from each measurement to the next, independent
    of the others. `by` (N,3,3): how a change of the ambient moves each sample's reference (None: one to
    one, as for coils; a turntable turns it into the table's frame)."""
    times = np.asarray(times, float)
    if model.anchored:
        return _anchored_source(model, times, name, by)
    p = len(model.coef)
    x = np.column_stack([np.ones(len(times)), times - model.t0])[:, :p]  # (N,p)
    epoch = model.epochs(times)
    epochs = int(epoch.max()) + 1
    a = np.zeros((len(times), 3, 3 * (p + epochs)))
    sigma = np.zeros((3 * (p + epochs),) * 2)
    rows = np.arange(len(times))
    for i in range(3):
        idx = [3 * k + i for k in range(p)]
        a[:, i, idx] = x
        sigma[np.ix_(idx, idx)] = 0.5 * (model.cov[i] + model.cov[i].T)  # pinv's rounding: symmetric
        a[rows, i, 3 * (p + epoch) + i] = 1.0
        for e in range(epochs):
            sigma[3 * (p + e) + i, 3 * (p + e) + i] = model.excess_nt[i] ** 2
    if by is not None:
        a = np.einsum("nij,njq->niq", by, a)
    drift = " with a drift" if model.drifting else ""
    excess = ", ".join(f"{v:.1f}" for v in model.excess_nt)
    scatter = [(3 * (p + np.arange(epochs)) + i, np.full(epochs, model.excess_nt[i] ** 2)) for i in range(3)]
    return InputSource(name, sigma, ref_nt=a, shared=name, estimated=_estimated(model, scatter),
                       origin=f"measured {model.n} time(s){drift}; scatter beyond their noise ({excess}) "
                       "nT, an offset of its own between measurements")


def _estimated(model, per_axis) -> tuple[Estimated, ...]:
    """The excess scatter is estimated from the model's n measurements less its p coefficients, one
    estimate per axis: its parts of the source's variances (`per_axis`: (index, variance) per axis)."""
    dof = max(model.n - len(model.coef), 1)
    return tuple(Estimated(index, variance, dof) for index, variance in per_axis if np.any(variance > 0))


def _anchored_source(model, times, name: str, by) -> InputSource:
    """ambient_source where each epoch is its own measurement carried on by the drift: an offset per epoch
    and axis of that measurement's standard error and the excess scatter, and the drift's slope error
    times the time since."""
    e = model.epochs(times)
    epochs = len(model.anchors)
    drift = model.drifting
    q = 3 * epochs + (3 if drift else 0)
    a = np.zeros((len(times), 3, q))
    sigma = np.zeros((q, q))
    rows = np.arange(len(times))
    for i in range(3):
        a[rows, i, 3 * e + i] = 1.0
        sigma[np.arange(epochs) * 3 + i, np.arange(epochs) * 3 + i] = model.anchor_se[:, i] ** 2 + \
            model.excess_nt[i] ** 2
        if drift:
            a[:, i, 3 * epochs + i] = times - model.measured_t[e]
            sigma[3 * epochs + i, 3 * epochs + i] = model.cov[i][1, 1]
    if by is not None:
        a = np.einsum("nij,njq->niq", by, a)
    excess = ", ".join(f"{v:.1f}" for v in model.excess_nt)
    # per axis: the excess in every epoch's offset, and the drift's slope (widened by the same scatter)
    scatter = [(np.append(3 * np.arange(epochs) + i, [3 * epochs + i] if drift else []).astype(int),
                np.append(np.full(epochs, model.excess_nt[i] ** 2), [model.cov[i][1, 1]] if drift else []))
               for i in range(3)]
    return InputSource(name, sigma, ref_nt=a, shared=name, estimated=_estimated(model, scatter),
                       origin=f"measured {model.n} time(s){' with a drift' if drift else ''}; scatter beyond "
                       f"their noise ({excess}) nT: each epoch its own measurement, the lab moving that much "
                       "again within it")


def by_position(r_m) -> np.ndarray:
    """(3, 5): G r = this @ g for an offset r in metres (or (N,3,5) for offsets (N,3)). Where the lab field
    has no sources (no currents, no magnetised material) its gradient is symmetric and traceless: five
    numbers g = (Gxx, Gyy, Gxy, Gxz, Gyz), Gzz = -Gxx - Gyy."""
    r = np.asarray(r_m, float)
    x, y, z = r[..., 0], r[..., 1], r[..., 2]
    zero = np.zeros_like(x)
    return np.stack([np.stack([x, zero, y, z, zero], -1), np.stack([zero, y, x, zero, z], -1),
                     np.stack([-z, -z, zero, x, y], -1)], -2)


def stated_gradient_source(offsets_m, bound_nt_per_m: float, by=None) -> InputSource:
    """The lab field's gradient within a stated +-bound on each of its five source-free components
    (by_position; rectangular) as a line of the budget: a sample's reference misses G (offset),
    `offsets_m` (N,3) being where the DUT was from the reference magnetometer that measured the ambient;
    `by` as for ambient_source. The symmetry matters: Gxz and Gzx are one number, so a DUT turned through
    the gradient sees their effects add, not add in quadrature."""
    a = by_position(offsets_m)
    if by is not None:
        a = np.einsum("nij,njq->niq", by, a)
    return InputSource("ambient gradient", np.eye(5) * bound_nt_per_m**2 / 3.0, ref_nt=a,
                       distribution="rectangular", shared="ambient gradient",
                       origin=f"stated: +-{bound_nt_per_m:g} nT/m on each of its five source-free components")
