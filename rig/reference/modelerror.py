"""What a calibration's model leaves out, as lines of its budget: the model checks' terms and the misfit.

    direction = thermal_direction(times, temps, history)       # +1 heating, -1 cooling, 0 unknown
    record_model_checks(cal, ds, direction)                    # cal.stats["model_checks"] (T24)
    sources, notes = model_sources(ds, cal, direction, weights)

What the parameters stand for: the T24 model that describes the DUT best over the calibration's fields
and temperatures, in its mean thermal state. A term T24 lacks then costs the calibrated field what T24
cannot follow of it, and a thermal hysteresis costs the parameters what the fit took from an unbalanced
history besides:

- The model checks (calib/checks.py): T24 against T24 plus one deviation (a quadratic temperature term,
  a thermal hysteresis of the offset, a cubic field term). The terms the checks find (p < P_TERM) are
  fitted together with T24 (over a few temperature steps a curvature and a hysteresis share what the
  steps show: their estimates are correlated) and enter the budget as one source whose quantities are
  their coefficients, as u^2 + b^2 (the estimate b, uncorrected, a bias of unknown sign): a curvature or
  a cubic term moves the true field at the grid points by what a T24 fit over the grid cannot follow of
  it (calib.propagation InputSource.field_nt); the hysteresis moved the data by d_n c (d_n the thermal
  direction of each sample), which the parameters absorbed. At a point of use the DUT may be in either
  thermal state: +-c, a field error of its own ("thermal hysteresis state"). Another model's parameters
  (P12, the scalar fit, T36) absorb the hysteresis alike: their budgets take it as T24's checks find it
  in the same data; what else they cannot follow is in their own residual (the misfit).
- The misfit: the fit's residual (after those terms) beyond what the DUT's own noise explains. The noise
  is the scatter within points (the samples of one point see the same field and temperature); the
  excess, when significant (MISFIT_SIGNIFICANCE standard errors of the variance ratio), is a field error
  at every grid point that no parameter carries. A stated uncertainty below the measured scatter is then
  impossible. Where part of the residual is an affine function of the field (a model without some linear
  term: P12 has no rotation) and the data's directions are unbalanced (a turntable's), that part is larger
  at the directions the data did not visit: the misfit takes its size over every direction. With one
  sample a point the noise cannot be told from the misfit: a note says so.
"""

from __future__ import annotations

import numpy as np

from calib.checks import FIELD_SCALE_NT, model_checks
from calib.design import regressors as t24_regressors
from calib.propagation import InputSource
from rig.reference.wander import wander_source

P_TERM = 1e-2  # a check whose p is below this puts its term in the budget
MISFIT_SIGNIFICANCE = 3.0
AFFINE_SIGNIFICANCE = 3.0  # standard errors beyond the affine part the noise alone would give
SIGNIFICANT = 3.0  # standard errors: a point-level error counts
THERMAL_PLAY_C = 1.0  # a temperature change beyond this reverses the thermal direction
CHECK_TERMS = {"linearity in temperature": "temperature", "thermal hysteresis": "hysteresis",
               "linearity in the field": "field"}


def thermal_direction(times, temps, history=None, play_c: float = THERMAL_PLAY_C) -> np.ndarray:
    """(N,): +1 where the last temperature move beyond `play_c` before a sample was up, -1 down, 0 none
    yet; `history` ((t, temp_c) pairs, e.g. the session's temperature log) adds what came before and
    between the samples."""
    times, temps = np.asarray(times, float), np.asarray(temps, float)
    t_all, temp_all = times, temps
    if history:
        h = np.asarray(history, float).reshape(-1, 2)
        t_all, temp_all = np.r_[h[:, 0], times], np.r_[h[:, 1], temps]
    order = np.argsort(t_all, kind="stable")
    state, low, high = 0.0, np.inf, -np.inf
    seen = np.empty(len(order))
    for k in order:
        value = temp_all[k]
        low, high = min(low, value), max(high, value)
        if state >= 0 and value < high - play_c:
            state, low, high = -1.0, value, value
        elif state <= 0 and value > low + play_c:
            state, low, high = 1.0, value, value
        seen[k] = state
    return seen[len(t_all) - len(times):]


def record_model_checks(cal, ds, direction) -> None:
    """T24's model checks in the calibration's stats, for its budget and for acceptance."""
    cal.stats["model_checks"] = [c.as_dict() for c in model_checks(ds, direction)]


def _terms(kind: str, h, temp, direction, temp_mid: float) -> np.ndarray:
    """(N,3,k): the term's regressors per output axis (the same k per axis)."""
    n = len(h)
    if kind == "temperature":
        z = ((temp - temp_mid) ** 2)[:, None] * np.column_stack([h, np.ones(n)])  # (N,4)
        return np.repeat(z[:, None, :], 3, axis=1)
    if kind == "hysteresis":
        return np.repeat(np.asarray(direction, float).reshape(n, 1, 1), 3, axis=1)
    norm2 = np.sum(h * h, axis=1) / FIELD_SCALE_NT**2
    return (norm2[:, None] * h)[:, :, None]


def _checks(cal, ds, direction) -> dict[str, dict]:
    """T24's model checks by term (recorded in the stats, else made here: another model's data)."""
    checks = cal.stats.get("model_checks")
    if checks is None:
        checks = [c.as_dict() for c in model_checks(ds, direction)]
    return {CHECK_TERMS[c["name"]]: c for c in checks if c["name"] in CHECK_TERMS}


def _found(checks: dict[str, dict]) -> list[str]:
    """The terms the data show."""
    return [kind for kind, c in checks.items()
            if c.get("testable") and c.get("p") is not None and c["p"] < P_TERM]


def _joint_fit(x_base: np.ndarray, z: np.ndarray, ref: np.ndarray, w: np.ndarray):
    """Per output axis, ref_i on [x_base, z[:, i]] (rows weighted): (coefficients of z (3,k), their
    covariance for white noise (3,k,k), residuals (N,3), dof, the linear maps from ref_i to them (3,k,N))."""
    k = z.shape[2]
    coef, cov, resid = np.zeros((3, k)), np.zeros((3, k, k)), np.zeros_like(ref)
    maps = np.zeros((3, k, len(ref)))
    used = w > 0
    dof = int(used.sum()) - x_base.shape[1] - k
    for i in range(3):
        x = np.column_stack([x_base, z[:, i, :]])
        scale = np.linalg.norm(x[used], axis=0)
        scale[scale == 0] = 1.0
        xs = x[used] / scale
        u, s, vt = np.linalg.svd(xs * np.sqrt(w[used])[:, None], full_matrices=False)
        beta = (vt.T @ ((u.T @ (ref[used, i] * np.sqrt(w[used]))) / s)) / scale
        resid[:, i] = ref[:, i] - x @ beta
        sigma2 = float(np.sum(w[used] * resid[used, i] ** 2) / max(dof, 1))
        inv = (vt.T / s**2) @ vt / np.outer(scale, scale)
        first = x.shape[1] - k  # the terms' columns (none when k = 0)
        coef[i], cov[i] = beta[first:], sigma2 * inv[first:, first:]
        maps[i][:, used] = (((vt.T / s) @ u.T) * np.sqrt(w[used]) / scale[:, None])[first:]
    return coef, cov, resid, dof, maps


def within_point_noise(residuals: np.ndarray, points) -> tuple[np.ndarray, int]:
    """(per axis RMS scatter of the residuals within points, its degrees of freedom)."""
    labels, index = np.unique(np.asarray(points, object).astype(str), return_inverse=True)
    counts = np.bincount(index, minlength=len(labels))
    means = np.stack([np.bincount(index, residuals[:, i], len(labels)) for i in range(residuals.shape[1])],
                     axis=1) / np.maximum(counts, 1)[:, None]
    dof = int(np.sum(np.maximum(counts - 1, 0)))
    if dof == 0:
        return np.full(residuals.shape[1], np.nan), 0
    return np.sqrt(np.sum((residuals - means[index]) ** 2, axis=0) / dof), dof


def model_sources(ds, cal, direction, weights=None,
                  step_reference_var=None) -> tuple[list[InputSource], list[str], np.ndarray | None]:
    """The budget's model-check sources (T24), its misfit and the offset's wander (rig/reference/wander.py),
    with notes; and for T24 the readings' noise the fit's statistics should take: the residual of T24 with
    the checks' terms (their share of the plain residual is budgeted by the terms' source), widened where
    the samples of a point share an error. step_reference_var (3,): the variance of the reference's own
    error from one temperature step to the next (the ambient's scatter between its measurements), which
    the terms' estimates share with the offset's wander."""
    notes: list[str] = []
    w = np.ones(len(ds)) if weights is None else np.asarray(weights, float)
    points = ds.columns.get("point")
    fit = _TermsFit(ds, cal, direction, w) if cal.model == "t24" else None
    # another model's parameters take the DUT's thermal hysteresis from an unbalanced history as T24's do:
    # its size is what T24's checks find in the same data
    other = None if fit is not None or ds.ref_nt is None or direction is None else \
        _TermsFit(ds, cal, direction, w)
    if fit is not None:
        resid, dof = fit.resid, fit.dof
    elif cal.model == "scalar":
        if ds.ref_nt is None:
            return [], ["misfit: the data have no reference field"], None
        field = cal.apply(ds.h_nt, ds.temp_c)
        resid = (np.linalg.norm(field, axis=1) - np.linalg.norm(ds.ref_nt, axis=1))[:, None]
        dof = int((w > 0).sum()) - sum(int(np.size(v)) for v in cal.params.values())
    else:
        resid = ds.ref_nt - cal.apply(ds.h_nt, ds.temp_c)
        dof = int((w > 0).sum()) - sum(int(np.size(v)) for v in cal.params.values()) // 3
    out: list[InputSource] = []
    step_var = None
    if resid.shape[1] == 3 and points is not None:
        noise, _ = within_point_noise(resid[w > 0], np.asarray(points, object)[w > 0])
        wander, said, step_var = wander_source(ds, resid, noise, w)
        notes += [] if wander is not None else [said]
        out += [] if wander is None else [wander]
    if fit is not None:
        out = fit.sources(ds, cal, step_var, step_reference_var, notes) + out
    elif other is not None and "hysteresis" in other.found:
        # the hysteresis estimate shares the steps with T24's own wander, not with this model's residual,
        # which holds what the model cannot follow of the temperature
        t24_var = None
        if points is not None:
            t24_noise, _ = within_point_noise(other.resid[w > 0], np.asarray(points, object)[w > 0])
            t24_var = wander_source(ds, other.resid, t24_noise, w)[2]
        out = other.sources(ds, cal, t24_var, step_reference_var, notes, hysteresis_only=True) + out
    misfit = _misfit(resid, w, dof, points, notes, ds.ref_nt)
    noise = None
    if fit is not None:
        used = w > 0
        noise = np.sqrt(np.sum(w[used, None] * resid[used] ** 2, axis=0) / max(dof, 1))
        if points is not None:
            noise = _clustered_noise(resid[used], np.asarray(points, object)[used], noise, notes)
    return out + ([misfit] if misfit is not None else []), notes, noise


def _clustered_noise(resid: np.ndarray, points, rms: np.ndarray, notes: list[str]) -> np.ndarray:
    """The noise the fit's statistics should take when the samples of one point share part of their error
    (a slow offset noise, anything fixed for a point): with n samples a point, an offset of variance s^2
    common to them weighs in the fit as a white noise of variance n s^2 does (the design effect: the
    samples of a point have the same regressors), so sqrt(sigma_w^2 + n s^2), sigma_w the scatter within
    points; s^2 the point means' variance beyond what sigma_w gives them, when SIGNIFICANT standard errors
    above zero (pooled over the axes). Else the residual's RMS (its white-noise reading)."""
    noise_w, _ = within_point_noise(resid, points)
    labels, index = np.unique(np.asarray(points).astype(str), return_inverse=True)
    counts = np.bincount(index, minlength=len(labels))
    if not np.all(np.isfinite(noise_w)) or len(labels) < 3:
        return rms
    sums = np.stack([np.bincount(index, resid[:, i], len(labels)) for i in range(3)], axis=1)
    means = sums / counts[:, None]
    excess = np.mean(means**2 - noise_w**2 / counts[:, None], axis=1)  # per point, pooled over the axes
    s2, se = float(np.mean(excess)), float(np.std(excess, ddof=1) / np.sqrt(len(excess)))
    if s2 <= SIGNIFICANT * se:
        return rms
    n = float(np.mean(counts))
    taken = np.sqrt(noise_w**2 + n * s2)
    notes.append(f"fit (statistical): the samples of a point share an error of {np.sqrt(s2):.1f} nT beyond "
                 f"their noise ({_fmt(noise_w)}) nT: taken as a noise of ({_fmt(taken)}) nT for the {n:.0f} "
                 "samples a point")
    return taken


class _TermsFit:
    """T24 and the terms its checks found, fitted together (module docstring)."""

    def __init__(self, ds, cal, direction, w):
        self.checks = _checks(cal, ds, direction)
        self.found = _found(self.checks)
        temps = np.asarray(ds.temp_c, float)
        self.mid = 0.5 * (float(temps.min()) + float(temps.max()))
        moving = np.asarray(direction, float) if direction is not None else np.zeros(len(ds))
        self.parts = [(kind, _terms(kind, ds.h_nt, temps, moving, self.mid)) for kind in self.found]
        self.z = (np.concatenate([p for _, p in self.parts], axis=2) if self.parts
                  else np.zeros((len(ds), 3, 0)))
        x_base = t24_regressors(ds.h_nt, ds.temp_c, self.mid if cal.temp_ref_c is None else cal.temp_ref_c)
        self.coef, self.cov, self.resid, self.dof, self.maps = _joint_fit(x_base, self.z, ds.ref_nt, w)

    def _widened(self, ds, step_var) -> np.ndarray:
        """The terms' covariance per axis with an error of variance step_var (3,) per temperature step."""
        cov = self.cov.copy()
        if step_var is not None:
            groups = np.unique(np.asarray(ds.group, object).astype(str), return_inverse=True)[1]
            for i in range(3):
                per_step = np.stack([np.bincount(groups, row, groups.max() + 1) for row in self.maps[i]])
                cov[i] += step_var[i] * per_step @ per_step.T
        return cov

    def sources(self, ds, cal, wander_var, reference_var, notes: list[str],
                hysteresis_only: bool = False) -> list[InputSource]:
        """The terms as one source, their coefficients' covariance widened by what changes from one step
        to the next (the offset's wander, the reference's error), which the white-noise covariance misses:
        the terms share the steps with them; and the hysteresis state, the DUT's own hysteresis in use
        (its estimate's share of the reference's error is the first source's). hysteresis_only: for a
        model other than T24, whose own residual (the misfit) holds what it cannot follow of the other
        terms: the hysteresis alone, as it moved the data."""
        if not self.found:
            notes.append(f"model checks: no term beyond T24 found (p >= {P_TERM:g})")
            return []
        per_step = [v for v in (wander_var, reference_var) if v is not None]
        k, coef = self.z.shape[2], self.coef
        cov = self._widened(ds, np.sum(per_step, axis=0) if per_step else None)
        hysteresis = np.concatenate([np.full(p.shape[2], kind == "hysteresis") for kind, p in self.parts])
        sigma = np.zeros((3 * k, 3 * k))
        a = np.zeros((len(ds), 3, 3 * k))
        for i in range(3):
            block = slice(k * i, k * i + k)
            sigma[block, block] = cov[i] + np.outer(coef[i], coef[i])
            a[:, i, block] = np.where(hysteresis, self.z[:, i, :], 0.0)
        parts, mid = self.parts, self.mid

        def grid_effect(grid_h, grid_temp):
            """What a T24 fit over the grid cannot follow of each curvature or cubic term there."""
            h = np.asarray(grid_h, float)
            g_temp = np.full(len(h), mid) if grid_temp is None else np.asarray(grid_temp, float)
            zg = np.concatenate([_terms(kind, h, g_temp, np.zeros(len(h)), mid) for kind, _ in parts], axis=2)
            x = t24_regressors(h, g_temp, cal.temp_ref_c)
            out = np.zeros((len(h), 3, 3 * k))
            for i in range(3):
                left = zg[:, i, :] - x @ np.linalg.lstsq(x, zg[:, i, :], rcond=None)[0]
                out[:, i, k * i:k * i + k] = np.where(hysteresis, 0.0, left)
            return out

        checks = self.checks
        said = "; ".join(checks[kind]["message"] if kind in checks else f"{kind} term found"
                         for kind in self.found)
        if hysteresis_only:
            said = checks["hysteresis"]["message"] + "; fitted together with T24 on the same data (u^2 + b^2)"
            out = [InputSource("model checks (hysteresis)", sigma, ref_nt=a, origin=said)]
        else:
            out = [InputSource("model checks (" + ", ".join(self.found) + ")", sigma, ref_nt=a,
                               field_nt=grid_effect, origin=said + "; fitted together with T24 (u^2 + b^2)")]
        if "hysteresis" in self.found:
            at = int(np.flatnonzero(hysteresis)[0])
            own = self._widened(ds, wander_var)
            size = np.array([max(own[i][at, at], coef[i, at] ** 2) for i in range(3)])
            said = f"either thermal direction at a point of use: +-d ({_fmt(np.sqrt(size))}) nT"
            out.append(InputSource("thermal hysteresis state", np.diag(size), field_nt=everywhere,
                                   distribution="two-point", origin=said))
        return out


def directional_part(resid, ref, w, points=None) -> tuple[np.ndarray, np.ndarray] | None:
    """The residual's part that is an affine function of the field (per axis: c . B / |B|rms + c0), as
    a model without some linear term leaves it (P12 has no rotation), when it is beyond what the noise
    gives by chance (AFFINE_SIGNIFICANCE standard errors; counted in points, whose samples share their
    errors): (its mean square over the data, its mean square over every direction at the data's RMS
    magnitude, |c|^2 / 3 + c0^2). Over unbalanced directions (a turntable's) the second is the larger: the
    model's error at the directions the data did not visit. None: not significant, or no field."""
    used = w > 0
    if ref is None or resid.shape[1] != 3 or used.sum() < 8:
        return None
    ref_used = np.asarray(ref, float)[used]
    size = float(np.sqrt(np.mean(np.sum(ref_used**2, axis=1))))
    if size == 0:
        return None
    x = np.column_stack([ref_used / size, np.ones(len(ref_used))]) * np.sqrt(w[used])[:, None]
    r = resid[used] * np.sqrt(w[used])[:, None]
    coef = np.linalg.lstsq(x, r, rcond=None)[0]  # (4,3)
    n = len(np.unique(np.asarray(points, object)[used].astype(str))) if points is not None else len(r)
    total = np.sum(r**2, axis=0) / np.sum(w[used])
    in_data = np.sum((x @ coef) ** 2, axis=0) / np.sum(w[used])
    chance = (4 + AFFINE_SIGNIFICANCE * np.sqrt(8.0)) * total / max(n, 1)
    if not np.any(in_data > chance):
        return None
    everywhere_ms = np.sum(coef[:3] ** 2, axis=0) / 3 + coef[3] ** 2
    significant = in_data > chance
    return np.where(significant, in_data, 0.0), np.where(significant, everywhere_ms, 0.0)


def _misfit(resid, w, dof, points, notes, ref=None) -> InputSource | None:
    used = w > 0
    rms2 = np.sum(w[used, None] * resid[used] ** 2, axis=0) / max(dof, 1)
    if points is None:
        notes.append("misfit: the samples carry no point labels; the DUT's noise cannot be told from it")
        return None
    noise, noise_dof = within_point_noise(resid[used], np.asarray(points, object)[used])
    if noise_dof == 0:
        notes.append("misfit: one sample a point, the DUT's noise cannot be told from the misfit: not in the "
                     "budget (take two or more samples a point)")
        return None
    limit = 1.0 + MISFIT_SIGNIFICANCE * np.sqrt(2.0 / max(dof, 1) + 2.0 / noise_dof)
    excess2 = np.where(rms2 > limit * noise**2, rms2 - noise**2, 0.0)
    excess2 = np.broadcast_to(excess2, (3,)) if excess2.size == 1 else excess2
    rms = np.sqrt(np.broadcast_to(rms2, (3,)))
    noise3 = np.broadcast_to(noise, (3,))
    origin = (f"residual rms ({_fmt(rms)}) nT against the noise within points ({_fmt(noise3)}) nT: excess "
              f"({_fmt(np.sqrt(excess2))}) nT")
    directional = directional_part(resid, ref, w, points)
    if directional is not None and np.any(directional[1] > directional[0]):
        in_data, anywhere = directional
        excess2 = excess2 + np.maximum(anywhere - in_data, 0.0)
        origin += (f"; of the residual, an affine function of the field's direction "
                   f"({_fmt(np.sqrt(in_data))}) nT grows to ({_fmt(np.sqrt(anywhere))}) nT over every "
                   f"direction (the data's are not balanced): excess taken ({_fmt(np.sqrt(excess2))}) nT")
    excess = np.sqrt(excess2)
    return InputSource("misfit", np.diag(excess**2), field_nt=everywhere, origin=origin)


def everywhere(grid_h, grid_temp) -> np.ndarray:
    """(G,3,3): a field error of its own on each axis at every grid point."""
    return np.broadcast_to(np.eye(3), (len(grid_h), 3, 3))


def _fmt(values) -> str:
    return ", ".join(f"{v:.1f}" for v in values)
